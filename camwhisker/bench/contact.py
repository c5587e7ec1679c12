"""Evaluation of the contact back end on simulated stage experiments: errors, scores, speed.

:func:`calibrate_simulated` calibrates on simulated runs; :func:`evaluate_kind`
runs the pause-level pipeline on the runs of one experiment kind and attaches
the truth; :func:`summary` computes the contact numbers (RMSE and bias of
GM, MF and fused estimates, AUC and flag rates of both Z scores);
:func:`benchmark` times the vectorised core and prints samples/s beside the error.
:func:`run_bench` does all of it at each noise level of
:data:`~camwhisker.sim.mechanics.experiment.NOISE_LEVELS` (the paper's, our front end's).
"""

from __future__ import annotations

import time

import numpy as np

from camwhisker.bench.frames import evaluate_frames, format_frames
from camwhisker.contact.calibrate import CalibrationRun, calibrate
from camwhisker.contact.pipeline import Calibration, analyse_run, estimate, pause_estimates
from camwhisker.contact.shape import reconstruct
from camwhisker.contact.stage import stage_log_from_arrays
from camwhisker.contact.zscore import flag_rates, roc_auc
from camwhisker.sim.mechanics.experiment import NOISE_LEVELS, simulate_runs

__all__ = ["BAD_GM_ERROR_MM", "calibrate_simulated", "evaluate_run", "pool",
           "evaluate_kind", "summary", "benchmark",
           "run_bench", "format_report"]

EVAL_KINDS = ("rigid", "compliant", "slide-box", "slide-circle")

# A GM estimate this far off counts as a failure (the paper's 15 mm).
BAD_GM_ERROR_MM = 15.0


def _log(run, with_r: bool):
    return stage_log_from_arrays(run.stage["t_s"], run.stage["x_mm"],
                                 run.stage.get("r_mm") if with_r else None,
                                 source=f"<{run.kind}:{run.name} stage>")


def calibrate_simulated(seed: int, kind: str = "rigid", **sim) -> Calibration:
    """Calibrate on the simulated runs of ``kind``; offsets estimated.

    ``kind``: "rigid" (default: pegs at the paper's radii) or "eq8" (phi from
    eq. (8), for C recovery).
    """
    runs = simulate_runs(kind, seed, **sim)
    cal_runs = [CalibrationRun(r.signals, _log(r, True), f"<{kind}:{r.name} signals>")
                for r in runs]
    calib, _, _ = calibrate(cal_runs, l_w_mm=150.0, command=f"calibrate_simulated({seed})")
    return calib


def evaluate_run(calib: Calibration, signals: dict, log, truth: dict, scene,
                 true_offset_s: float, run_index: int = 0) -> dict:
    """Pause-level estimates of one run with its truth attached.

    Truth per pause (at its middle): r_true_mm, slipping, contact point, the
    distance of (x_hat, y_hat) to the true profile (profile_dist_mm), the
    offset error (offset_err_s), and the run index. ``signals`` may come from
    the simulator or from the vision front end on a filmed run.
    """
    a = analyse_run(signals, log)
    e = pause_estimates(calib, a)
    tmid = 0.5 * (a.pauses.t_start_s + a.pauses.t_end_s)
    e["r_true_mm"] = np.interp(tmid, truth["t_s"], truth["r_mm"])
    slipping = np.asarray(truth["slipping"], float)
    e["slipping"] = np.interp(tmid, truth["t_s"], slipping) > 0.5
    e["profile_dist_mm"] = scene.profile_distance(e["x_hat_mm"], e["y_hat_mm"])
    gx, gy = reconstruct(e["x_mm"], e["r_gm_mm"], e["phi_deg"], e["dz_mm"], a.travel_sign,
                         calib.gm, calib.bend)
    mx, my = e["x_mf_mm"], e["y_mf_mm"]
    e["gm_x_hat_mm"], e["gm_y_hat_mm"], e["mf_x_hat_mm"], e["mf_y_hat_mm"] = gx, gy, mx, my
    e["gm_profile_dist_mm"] = scene.profile_distance(gx, gy)
    e["offset_err_s"] = np.full(tmid.size, a.offset_s - true_offset_s)
    e["run"] = np.full(tmid.size, run_index)
    return e


def pool(parts: list[dict]) -> dict:
    """Concatenate per-run evaluations into one."""
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def evaluate_kind(calib: Calibration, kind: str, seed: int, **sim) -> dict:
    """:func:`evaluate_run` over all simulated runs of ``kind``, pooled."""
    return pool([
        evaluate_run(calib, run.signals, _log(run, False), run.truth, run.scene, run.offset_s, i)
        for i, run in enumerate(simulate_runs(kind, seed, **sim))
    ])


def summary(ev: dict) -> dict:
    """Errors and score quality on samples where GM, MF and the truth are all defined."""
    r = ev["r_true_mm"]
    gm = np.isfinite(r) & np.isfinite(ev["r_gm_mm"])
    both = gm & np.isfinite(ev["r_mf_mm"])
    # n_gm - n: pauses below MF's phi floor (or outside its table), left out of every number.
    out = {"n": int(both.sum()), "n_gm": int(gm.sum())}
    for name in ("r_gm_mm", "r_mf_mm", "r_fused_mm"):
        err = (r - ev[name])[both]
        key = name[2:-3]
        out[f"{key}_rmse_mm"] = float(np.sqrt(np.mean(err**2))) if err.size else np.nan
        out[f"{key}_mean_mm"] = float(np.mean(err)) if err.size else np.nan
    bad = np.abs(r - ev["r_gm_mm"]) > BAD_GM_ERROR_MM
    out["n_bad"] = int((bad & both).sum())
    for z in ("z_score", "z_combined"):
        s = np.where(both, ev[z], np.nan)
        hit, false = flag_rates(s, bad, 1.0)
        out[f"{z}_auc"] = roc_auc(s, bad)
        out[f"{z}_hit"] = hit
        out[f"{z}_false"] = false
    # The fusion's run-level evidence: posterior probability that GM failed, flagged > 0.5.
    p_bad = np.where(both, 1.0 - ev["p_gm_good"], np.nan)
    out["p_bad_auc"] = roc_auc(p_bad, bad)
    out["p_bad_hit"], out["p_bad_false"] = flag_rates(p_bad, bad, 0.5)
    return out


def benchmark(calib: Calibration, n: int = 100_000, repeats: int = 5, seed: int = 0) -> dict:
    """Time :func:`~camwhisker.contact.pipeline.estimate` on n random samples.

    Returns samples per second and microseconds per sample (best of ``repeats``).
    """
    rng = np.random.default_rng(seed)
    t = calib.mf_table
    k = rng.integers(0, len(t), n)
    phi = t.phi_deg[k] + 0.1 * rng.standard_normal(n)
    dz = t.dz_mm[k] + 0.01 * rng.standard_normal(n)
    dx = np.abs(rng.normal(10.0, 5.0, n)) + 0.1
    x = dx
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        estimate(calib, x, dx, phi, dz, 1.0)
        best = min(best, time.perf_counter() - t0)
    return {"samples": n, "seconds": best, "samples_per_s": n / best,
            "us_per_sample": 1e6 * best / n}


def run_bench(seed: int, calib: Calibration | None = None, figures_dir=None,
              n_timing: int = 100_000, noise_levels: dict | None = None,
              speeds_mm_s: tuple = (1.0, 2.5, 5.0)) -> dict:
    """Calibrate on rigid runs of ``seed``, evaluate all kinds on ``seed + 1``, per noise level.

    Each level of ``noise_levels`` (default
    :data:`~camwhisker.sim.mechanics.experiment.NOISE_LEVELS`: the paper's noise and our front
    end's) gets its own calibration (unless ``calib`` is given) and evaluation, as a sensor with
    that noise would.

    Per level also the per-frame scores (:mod:`camwhisker.bench.frames`) of paused
    runs and of continuous sweeps at each of ``speeds_mm_s``.

    Returns {"levels": {level: {"noise", "summaries", "calib", "evaluations", "frames"}},
    "timing": benchmark}. With ``figures_dir``, writes fig8_errors.png and
    fig9_shapes.png (first level) there.
    """
    levels = noise_levels or NOISE_LEVELS
    out = {"levels": {}}
    for name, noise in levels.items():
        cal = calib or calibrate_simulated(seed, noise=noise)
        evs = {k: evaluate_kind(cal, k, seed + 1, noise=noise) for k in EVAL_KINDS}
        frames = [evaluate_frames(cal, seed + 1, v, noise=noise) for v in (None, *speeds_mm_s)]
        out["levels"][name] = {"noise": noise, "summaries": {k: summary(e) for k, e in evs.items()},
                               "calib": cal, "evaluations": evs, "frames": frames}
    first = next(iter(out["levels"].values()))
    out["timing"] = benchmark(first["calib"], n=n_timing)
    if figures_dir is not None:
        from pathlib import Path

        from camwhisker.contact.plots import plot_error_boxes, plot_shapes
        from camwhisker.sim.mechanics.experiment import _scenes

        name = next(iter(out["levels"]))
        noise = first["noise"]
        evs = first["evaluations"]
        how = (f"simulated, {name} noise (phi {noise.phi_deg} deg, dz {noise.dz_mm} mm), "
               f"calibration seed {seed}, evaluation seed {seed + 1}")
        d = Path(figures_dir)
        plot_error_boxes({k: evs[k] for k in ("rigid", "compliant")}, d / "fig8_errors.png",
                         "Fig. 8: " + how)
        from camwhisker.bench.percepts import fitted_outline

        outlines = {k: _scenes(k)[0][1].outline() for k in ("slide-box", "slide-circle")}
        plot_shapes({k: evs[k] for k in outlines}, outlines, d / "fig9_shapes.png",
                    "Fig. 9: " + how, {k: fitted_outline(evs[k]) for k in outlines})
    return out


def format_report(result: dict) -> str:
    """Error and speed side by side: per noise level, one line per contact kind."""
    t = result["timing"]
    lines = [f"back end: {t['samples_per_s']:,.0f} samples/s ({t['us_per_sample']:.2f} us/sample,"
             f" {t['samples']} samples, vectorised estimate())"]
    for name, level in result["levels"].items():
        noise = level["noise"]
        lines.append("")
        lines.append(f"noise level '{name}': phi {noise.phi_deg} deg, dz {noise.dz_mm} mm"
                     " per frame")
        lines.append(f"{'kind':<13}{'n/N':>8}{'GM rmse':>9}{'GM mean':>9}{'MF rmse':>9}{'fused':>8}"
                     f"{'bad':>5}{'Z11 AUC':>9}{'Z11 hit':>8}{'Z11 ff':>7}{'Zc AUC':>8}"
                     f"{'Zc hit':>7}{'Zc ff':>6}{'Pb AUC':>8}{'Pb hit':>7}{'Pb ff':>6}")
        for kind, s in level["summaries"].items():
            n = f"{s['n']}/{s['n_gm']}"
            lines.append(
                f"{kind:<13}{n:>8}{s['gm_rmse_mm']:>9.2f}{s['gm_mean_mm']:>9.2f}"
                f"{s['mf_rmse_mm']:>9.2f}{s['fused_rmse_mm']:>8.2f}{s['n_bad']:>5}"
                f"{s['z_score_auc']:>9.3f}{s['z_score_hit']:>8.2f}{s['z_score_false']:>7.2f}"
                f"{s['z_combined_auc']:>8.3f}{s['z_combined_hit']:>7.2f}"
                f"{s['z_combined_false']:>6.2f}{s['p_bad_auc']:>8.3f}{s['p_bad_hit']:>7.2f}"
                f"{s['p_bad_false']:>6.2f}")
        lines.append("  per frame (contact --per frame; frames in contact, true phi >= 2 deg;"
                     " offset estimated, error in frames):")
        lines += ["    " + line for line in format_frames(level["frames"])]
        calib = level["calib"]
        lines.append("  calibration (rigid), Table II style: phi bin  n  mu_GM sigma_GM  mu_MF"
                     f" sigma_MF  [GM model: {calib.gm.kind}]")
        for g, m in zip(calib.gm_spread.rows(), calib.mf_spread.rows(), strict=True):
            lines.append(f"    {g[0]:4.1f}-{g[1]:<4.1f} {g[2]:>4d} {g[3]:6.2f} {g[4]:6.2f}  "
                         f"{m[3]:6.2f} {m[4]:6.2f}")
    lines.append("")
    lines.append("n/N: pauses with GM and MF / with GM (MF starts at the calibration's phi"
                 " floor); errors in mm (r - r_hat, pause medians) over the n; bad: |GM error| >"
                 " 15 mm; hit / ff:"
                 " share of bad / good samples flagged (Z > 1; Pb > 0.5); paper's ff: 0.26;"
                 " Z11: eq. (11); Zc: combined spread; Pb: fusion's P(GM failed); nan: no bad"
                 " samples in that scene")
    return "\n".join(lines)
