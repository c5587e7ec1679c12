"""Figures of the contact back end (PNG, written atomically; no pyplot, no backend chosen).

- :func:`plot_gm_model`: eq.-(8) and beam GM models against calibration data
  (r against dx / phi, one point per stage pause), like the paper's Fig. 7A.
- :func:`plot_error_boxes`: r - r_hat of GM, MF and fused for rigid and
  compliant contact (Fig. 8).
- :func:`plot_shapes`: reconstructed contact points coloured by Z with the
  true outline and the percept's fitted one (Fig. 9).
- :func:`plot_percept`: the surfels of a percept and its fitted outline.
- :func:`plot_texture`: the tip's push while sliding, filtered, its extrema, the ringing.

Every figure carries a footer and PNG metadata saying how it was made.
"""

from __future__ import annotations

import numpy as np

from camwhisker.contact.gm import r_gm_eq8
from camwhisker.files.figures import new_figure, save_figure

__all__ = ["plot_gm_model", "plot_error_boxes", "plot_shapes", "plot_percept", "plot_texture"]


def plot_gm_model(calib, data: dict, path, how: str = "") -> None:
    """Known r against measured dx / phi, one point per calibration pause, with the
    fitted GM models."""
    fig, ax = new_figure((6, 4.8))
    ok = np.isfinite(data["dx_mm"]) & (data["phi_deg"] >= 1.0)
    q = data["dx_mm"][ok] / data["phi_deg"][ok]
    r = data["r_mm"][ok]
    # Each pause its own point: the contact slides along the whisker within a run, so
    # the known r is not one value per run (boxes per r came out dozens, a few px wide).
    ax.plot(q, r, "o", ms=4, mfc="none", mec="k", mew=0.7,
            label=f"measured: {q.size} calibration pauses (known r)")
    qq = np.linspace(1e-3, max(q.max(), 1e-2) * 1.05, 200)
    beam = calib.gm.alternatives.get("beam")
    if beam is not None:  # r from dx and phi apart: no one curve in dx / phi, so per sample
        ax.plot(q, beam.r_mm(data["dx_mm"][ok], data["phi_deg"][ok]), "+", ms=4, color="C2",
                label="beam model at each pause", zorder=3)
    eq8 = calib.gm.alternatives.get("eq8")
    if eq8 is not None:
        c = eq8.params["c"]
        ax.plot(qq, r_gm_eq8(qq, 1.0, c, calib.l_w_mm, phi_min_deg=0.0), "r-",
                label=f"eq. (8), C = {c:.1f}")
    ax.set_xlabel("dx / phi (mm / deg)")
    ax.set_ylabel("r (mm)")
    ax.set_title(f"GM model vs calibration data (used: {calib.gm.kind})")
    ax.legend(loc="lower right", fontsize=8)
    save_figure(fig, path, how or "GM model vs data (Fig. 7A)")


def plot_error_boxes(evaluations: dict, path, how: str = "") -> None:
    """Boxes of r - r_hat for GM, MF and fused, per contact kind (e.g. rigid, compliant)."""
    fig, ax = new_figure((7, 4.8))
    data, labels = [], []
    for kind, ev in evaluations.items():
        for name, key in (("GM", "r_gm_mm"), ("MF", "r_mf_mm"), ("fused", "r_fused_mm")):
            e = ev["r_true_mm"] - ev[key]
            data.append(e[np.isfinite(e)])
            labels.append(f"{kind}\n{name}")
    ax.boxplot(data, tick_labels=labels)
    ax.axhline(0.0, color="0.5", lw=0.8)
    ax.set_ylabel("r - r_hat (mm)")
    ax.set_title("Contact distance error (Fig. 8)")
    save_figure(fig, path, how or "error boxes (Fig. 8)")


def plot_shapes(evaluations: dict, outlines: dict, path, how: str = "",
                fitted: dict | None = None) -> None:
    """Fig. 9: reconstructed points (GM r, eq. 12) coloured by eq.-(11) Z; MF grey, fused x.

    The colour bands are the paper's reading of Z (< 0.5 expected, 0.5-1, > 1 probable
    error); points where the simulated contact truly slips are ringed in black.
    ``fitted`` maps a panel to (x, y, label): the percept's outline, dashed.
    """
    from matplotlib.colors import BoundaryNorm, ListedColormap

    cmap = ListedColormap(["#2c7bb6", "#fdae61", "#d7191c"])
    norm = BoundaryNorm([-1e9, 0.5, 1.0, 1e9], cmap.N)
    n = len(evaluations)
    fig, axes = new_figure((5.5 * n, 5.2), nrows=1, ncols=n, squeeze=False)
    for ax, (kind, ev) in zip(axes[0], evaluations.items(), strict=True):
        ox, oy = outlines[kind]
        ax.plot(ox, oy, "k-", lw=1, label="true outline")
        if fitted and kind in fitted:
            fx, fy, label = fitted[kind]
            ax.plot(fx, fy, "--", color="C4", lw=1.5, zorder=6, label=label)
        ax.scatter(ev["mf_x_hat_mm"], ev["mf_y_hat_mm"], s=8, c="0.7", label="MF")
        ax.scatter(ev["x_hat_mm"], ev["y_hat_mm"], s=14, c="k", marker="x", lw=0.7, zorder=5,
                   label="fused (the contact table's r_hat)")
        sc = ax.scatter(ev["gm_x_hat_mm"], ev["gm_y_hat_mm"], s=16, c=ev["z_score"], cmap=cmap,
                        norm=norm, zorder=3)
        for colour, band in zip(cmap.colors, ("Z < 0.5", "0.5 <= Z < 1", "Z >= 1"), strict=True):
            ax.scatter([], [], s=16, c=colour, label=f"GM, {band}")
        slip = np.asarray(ev["slipping"], bool) & np.isfinite(ev["gm_x_hat_mm"])
        if slip.any():
            ax.scatter(ev["gm_x_hat_mm"][slip], ev["gm_y_hat_mm"][slip], s=60,
                       facecolors="none", edgecolors="k", lw=0.8, zorder=4,
                       label="contact slipping (truth)")
        ax.set_aspect("equal")
        ax.set_title(kind)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        cb = fig.colorbar(sc, ax=ax, ticks=[0.5, 1.0], label="Z, eq. (11)")
        cb.ax.set_yticklabels(["0.5", "1"])
    # One legend below the panels: inside them it hid points.
    entries = {}
    for ax in axes[0]:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            entries.setdefault(label, handle)
    fig.legend(entries.values(), entries.keys(), loc="outside lower center", ncols=4,
               fontsize=8)  # fmt: skip
    save_figure(fig, path, how or "shape reconstruction (Fig. 9)")


def plot_percept(xy_mm, dirs, free_xy_mm, fit_xy, label: str, path, how: str = "") -> None:
    """Surfels (points with their directions), free space (the base) and the fitted outline."""
    fig, ax = new_figure((6, 5.6))
    xy = np.asarray(xy_mm, float).reshape(-1, 2)
    ax.scatter(xy[:, 0], xy[:, 1], s=14, c="k", marker="x", lw=0.7, label="contacts (eq. 12)")
    d = np.asarray(dirs, float).reshape(-1, 2)
    has = np.isfinite(d[:, 0])
    if has.any():
        ax.quiver(xy[has, 0], xy[has, 1], d[has, 0], d[has, 1], angles="xy", color="0.5",
                  width=0.003, label="surfel direction")
    free = np.asarray(free_xy_mm, float).reshape(-1, 2)
    if free.size:
        ax.plot(free[:, 0], free[:, 1], ".", ms=2, color="C0", label="whisker base (free)")
    if len(fit_xy[0]):
        ax.plot(fit_xy[0], fit_xy[1], "--", color="C4", lw=1.5, label=label)
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(label)
    fig.legend(loc="outside lower center", ncols=2, fontsize=8)
    save_figure(fig, path, how or "percept")


def plot_texture(est, path, how: str = "") -> None:
    """The tip's push over the recording, the low-passed signal with its extrema in the
    analysed stretch, and the free ringing the natural frequency comes from."""
    tr = est.trace
    t, u, y, win = tr["t_s"], tr["u_mm"], tr["filtered_mm"], tr["window"]
    fig, (ax, ax2) = new_figure((8, 6), nrows=2, ncols=1)
    ax.plot(t, u, "-", color="0.7", lw=0.7, label="tip's push u (signals)")
    ax.plot(t, y, "-", color="C0", lw=1.0, label=f"low-passed ({est.limits['cutoff_hz']:.2f} Hz)")
    if win.any():
        ax.axvspan(t[win][0], t[win][-1], color="C2", alpha=0.08, label="analysed")
    for key, mark in (("maxima", "^"), ("minima", "v")):
        times = tr.get(key, np.zeros(0))
        if len(times):
            ax.plot(times, np.interp(times, t, y), mark, color="C3", ms=4, label=key)
    title = (f"gap {est.gap_mm:.4g} ± {est.gap_se_mm:.2g} mm, amplitude {est.amplitude_mm:.4g} ± "
             f"{est.amplitude_se_mm:.2g} mm" if est.resolved
             else f"not resolved: gap >= {est.limits['gap_min_mm']:.3g} mm needed")
    ax.set_title(title)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("u (mm)")
    ax.legend(fontsize=7, ncols=3, loc="center")
    ring = slice(tr["ring0"], None)
    ax2.plot(t[ring], u[ring], "-", color="k", lw=0.8)
    ax2.set_title(f"free ringing: first mode {est.ringing.natural_hz:.3f} ± "
                  f"{est.ringing.natural_se_hz:.2g} Hz, damping ratio {est.ringing.damping:.3f}")
    ax2.set_xlabel("t (s)")
    ax2.set_ylabel("u (mm)")
    save_figure(fig, path, how or "texture")
