"""Gradient-Moment (GM) estimate of the radial contact distance, eq. (8), and a beam alternative.

Eq. (8) of the paper, with phi in degrees and dx in mm (:mod:`camwhisker.contact.eq8`,
which the simulator shares; its functions are re-exported here)::

    r_GM = C (dx / phi) l_w / (l_w + C dx / phi)

:func:`r_gm_beam` is the alternative derived from the small-deflection beam of
:mod:`camwhisker.sim.mechanics.whisker` (rigid rotation plus the cone's bending)::

    dx = r sin(phi) + beta phi r^2 / (3 (1 - kappa r))

with beta = k_phi / EI0 and kappa = 1 / L_a (the cone's apex length). It is
solved for r by vectorised bisection. :func:`fit_gm` fits both to calibration
data and keeps the one with the lower AIC.

Undefined estimates are NaN: phi below ``phi_min_deg`` (the GM divides by it),
dx <= 0 (no travel into the contact), non-finite inputs, or (beam) no r in
(0, l_w) that explains the data.

References
----------
Eq. (8): "Identifying Contact Distance Uncertainty in Whisker Sensing with
Tapered, Flexible Whiskers" (the seed paper of this project).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from camwhisker.contact.eq8 import PHI_MIN_DEG, defined, eq8_dx_mm, eq8_phi_deg, r_gm_eq8

# scipy.optimize and scipy.stats are imported where they are used: together they
# take ~1 s to import, and every command line builds its parser from modules
# that import this one.

__all__ = [
    "PHI_MIN_DEG",
    "GMFit",
    "r_gm_eq8",
    "eq8_phi_deg",
    "r_gm_beam",
    "r_gm",
    "deflection_mm",
    "fit_gm",
    "fit_c",
]

# Bisection iterations for the beam model: 2^-48 of l_w is far below a micron.
_BISECT_ITERATIONS = 48

# Confidence level of the interval reported with the fitted constants.
CONFIDENCE = 0.95
# Bootstrap resamples of whole runs for the CI of C: errors within a run share
# its contact onset and clock offset, so samples are not independent. 400 puts
# the Monte-Carlo error of a 2.5 % quantile well below the interval's width.
BOOTSTRAP_RESAMPLES = 400


def _beam_travel(r, sin_phi, bend, kappa_per_mm):
    """The beam's dx = r sin(phi) + beta phi r^2 / (3 (1 - kappa r)), with sin(phi) and
    bend = beta phi / 3 (phi in radians) given: the bisection reuses them."""
    return r * sin_phi + bend * r * r / (1.0 - kappa_per_mm * r)


def _beam_r_max(kappa_per_mm, l_w_mm):
    return l_w_mm if kappa_per_mm * l_w_mm < 1.0 else (1.0 - 1e-9) / kappa_per_mm


def r_gm_beam(dx_mm, phi_deg, beta_per_mm, kappa_per_mm, l_w_mm, phi_min_deg=PHI_MIN_DEG):
    """Radial contact distance from the small-deflection beam (module docstring).

    Solves dx = r sin(phi) + beta phi r^2 / (3 (1 - kappa r)) for r in (0, r_max),
    r_max = min(l_w, 1 / kappa); the right side increases with r, so the root is
    unique. NaN where undefined or where the root would lie beyond r_max.
    """
    dx = np.asarray(dx_mm, dtype=float)
    phi_deg = np.asarray(phi_deg, dtype=float)
    dx, phi_deg = np.broadcast_arrays(dx, phi_deg)
    if dx.size == 1:  # the live loop's one row: numpy's per-call overhead was 0.3 ms a frame
        r = _r_gm_beam_one(dx.item(), phi_deg.item(), beta_per_mm, kappa_per_mm, l_w_mm,
                           phi_min_deg)  # fmt: skip
        return np.full(dx.shape, r)
    ok = defined(dx, phi_deg, phi_min_deg)
    phi = np.radians(np.where(ok, phi_deg, PHI_MIN_DEG))
    dxv = np.where(ok, dx, 0.0)
    r_max = _beam_r_max(kappa_per_mm, l_w_mm)
    sin_phi = np.sin(phi)
    bend = beta_per_mm * phi / 3.0

    def travel(r):
        return _beam_travel(r, sin_phi, bend, kappa_per_mm)

    ok &= travel(np.full(dx.shape, r_max)) >= dxv
    lo = np.zeros(dx.shape)
    hi = np.full(dx.shape, r_max)
    for _ in range(_BISECT_ITERATIONS):
        mid = 0.5 * (lo + hi)
        below = travel(mid) < dxv
        lo = np.where(below, mid, lo)
        hi = np.where(below, hi, mid)
    return np.where(ok, 0.5 * (lo + hi), np.nan)


def _r_gm_beam_one(dx, phi_deg, beta_per_mm, kappa_per_mm, l_w_mm, phi_min_deg):
    """:func:`r_gm_beam` of one row in Python floats: the same operations in the same order
    (sin and radians by numpy), so the same bits."""
    if not bool(defined(np.float64(dx), np.float64(phi_deg), phi_min_deg)):
        return math.nan
    phi = float(np.radians(phi_deg))
    sin_phi = float(np.sin(phi))
    bend = beta_per_mm * phi / 3.0
    r_max = _beam_r_max(kappa_per_mm, l_w_mm)
    if not _beam_travel(r_max, sin_phi, bend, kappa_per_mm) >= dx:
        return math.nan
    lo, hi = 0.0, r_max
    for _ in range(_BISECT_ITERATIONS):
        mid = 0.5 * (lo + hi)
        # _beam_travel(mid, ...) written out: a call per iteration is half the loop's time.
        if mid * sin_phi + bend * mid * mid / (1.0 - kappa_per_mm * mid) < dx:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@dataclass(frozen=True)
class GMFit:
    """A fitted GM model.

    ``kind`` is "eq8" (params: c) or "beam" (params: beta_per_mm, kappa_per_mm).
    ``ci`` holds (low, high) per parameter at :data:`CONFIDENCE`; ``rmse_mm``
    and ``aic`` are on the fitting data.
    """

    kind: str
    params: dict
    ci: dict
    rmse_mm: float
    aic: float
    n: int
    l_w_mm: float
    alternatives: dict = field(default_factory=dict)

    def r_mm(self, dx_mm, phi_deg, phi_min_deg=PHI_MIN_DEG):
        return r_gm(self, dx_mm, phi_deg, phi_min_deg)


def r_gm(fit: GMFit, dx_mm, phi_deg, phi_min_deg=PHI_MIN_DEG):
    """r_GM (mm) from a fitted model of either kind."""
    if fit.kind == "eq8":
        return r_gm_eq8(dx_mm, phi_deg, fit.params["c"], fit.l_w_mm, phi_min_deg)
    if fit.kind == "beam":
        p = fit.params
        return r_gm_beam(dx_mm, phi_deg, p["beta_per_mm"], p["kappa_per_mm"], fit.l_w_mm,
                         phi_min_deg)
    raise ValueError(f"unknown GM model kind {fit.kind!r} (known: eq8, beam)")


def deflection_mm(fit: GMFit, r_mm, phi_deg):
    """The lateral offset (mm) from the base's line of a contact at r with the base tilted by
    phi: the travel after which a stuck contact at r gives that phi (the fitted model read
    backwards). NaN where r lies outside the model's range or an input is NaN."""
    r = np.asarray(r_mm, dtype=float)
    phi = np.asarray(phi_deg, dtype=float)
    if fit.kind == "eq8":
        return eq8_dx_mm(r, phi, fit.params["c"], fit.l_w_mm)
    if fit.kind == "beam":
        k = fit.params["kappa_per_mm"]
        ok = (r > 0.0) & (r < _beam_r_max(k, fit.l_w_mm))
        ph = np.radians(phi)
        d = _beam_travel(np.where(ok, r, 0.0), np.sin(ph), fit.params["beta_per_mm"] * ph / 3.0, k)
        return np.where(ok, d, np.nan)
    raise ValueError(f"unknown GM model kind {fit.kind!r} (known: eq8, beam)")


def _ci(result, n):
    """Parameter confidence intervals from the Jacobian at the optimum."""
    k = result.x.size
    dof = max(n - k, 1)
    s2 = 2.0 * result.cost / dof
    jtj = result.jac.T @ result.jac
    cov = np.linalg.pinv(jtj) * s2
    from scipy.stats import t as student_t

    half = student_t.ppf(0.5 + CONFIDENCE / 2.0, dof) * np.sqrt(np.clip(np.diag(cov), 0, None))
    return [(float(v - h), float(v + h)) for v, h in zip(result.x, half, strict=True)]


def _clean(dx_mm, phi_deg, r_mm, phi_min_deg):
    dx = np.asarray(dx_mm, float).ravel()
    phi = np.asarray(phi_deg, float).ravel()
    r = np.asarray(r_mm, float).ravel()
    keep = defined(dx, phi, phi_min_deg) & np.isfinite(r) & (r > 0)
    if keep.sum() < 3:
        raise ValueError(
            f"GM fit needs at least 3 samples with phi >= {phi_min_deg} deg, dx > 0 and a "
            f"known r; got {int(keep.sum())}"
        )
    return dx[keep], phi[keep], r[keep]


def _aic(rss, n, k):
    return n * math.log(max(rss, 1e-300) / n) + 2 * k


def _fit_c_core(dx, phi, r, l_w_mm, phi_min_deg):
    # Start from the median of eq. (8) solved for C per sample.
    c0 = float(np.median(r * l_w_mm / ((l_w_mm - np.minimum(r, 0.99 * l_w_mm)) * dx / phi)))

    def resid(p):
        return r_gm_eq8(dx, phi, p[0], l_w_mm, phi_min_deg) - r

    from scipy.optimize import least_squares

    return least_squares(resid, [c0], bounds=([1e-9], [np.inf]), x_scale=[c0])


def fit_c(dx_mm, phi_deg, r_mm, l_w_mm, phi_min_deg=PHI_MIN_DEG, groups=None,
          seed: int = 0) -> GMFit:
    """Least-squares fit of C in eq. (8) to known contact distances r.

    Minimises sum (r - r_GM(dx, phi; C))^2 over the usable samples. With
    ``groups`` (run id per sample, >= 3 runs) the CI is a percentile bootstrap
    over whole runs (:data:`BOOTSTRAP_RESAMPLES`, fixed ``seed``); otherwise it
    comes from the Jacobian, which assumes independent samples.
    """
    g = None if groups is None else np.asarray(groups).ravel()
    keep = defined(np.asarray(dx_mm, float).ravel(), np.asarray(phi_deg, float).ravel(),
                  phi_min_deg) & np.isfinite(np.asarray(r_mm, float).ravel())
    dx, phi, r = _clean(dx_mm, phi_deg, r_mm, phi_min_deg)
    res = _fit_c_core(dx, phi, r, l_w_mm, phi_min_deg)
    rss = 2.0 * res.cost
    (ci,) = _ci(res, r.size)
    if g is not None and np.unique(g[keep]).size >= 3:
        g = g[keep & (np.asarray(r_mm, float).ravel() > 0)]
        ids = np.unique(g)
        rng = np.random.default_rng(seed)
        members = [np.flatnonzero(g == k) for k in ids]
        boot = []
        for _ in range(BOOTSTRAP_RESAMPLES):
            take = np.concatenate([members[k] for k in rng.integers(0, ids.size, ids.size)])
            boot.append(_fit_c_core(dx[take], phi[take], r[take], l_w_mm, phi_min_deg).x[0])
        tail = 100.0 * (1.0 - CONFIDENCE) / 2.0
        ci = (float(np.percentile(boot, tail)), float(np.percentile(boot, 100.0 - tail)))
    return GMFit(
        kind="eq8",
        params={"c": float(res.x[0])},
        ci={"c": ci},
        rmse_mm=math.sqrt(rss / r.size),
        aic=_aic(rss, r.size, 1),
        n=int(r.size),
        l_w_mm=float(l_w_mm),
    )


def fit_beam(dx_mm, phi_deg, r_mm, l_w_mm, phi_min_deg=PHI_MIN_DEG) -> GMFit:
    """Least-squares fit of (beta, kappa) of the beam GM model to known r."""
    dx, phi, r = _clean(dx_mm, phi_deg, r_mm, phi_min_deg)
    phi_rad = np.radians(phi)
    kappa_max = (1.0 - 1e-6) / l_w_mm

    # Residuals in travel (linear in beta, smooth in kappa) are well conditioned;
    # weighting by 1 / (d travel / d r) turns them into errors in r.
    def resid(p):
        beta, kappa = p
        a = 1.0 - kappa * r
        travel = r * np.sin(phi_rad) + beta * phi_rad * r * r / (3.0 * a)
        slope = np.sin(phi_rad) + beta * phi_rad * r * (2.0 - kappa * r) / (3.0 * a * a)
        return (travel - dx) / slope

    from scipy.optimize import least_squares

    res = least_squares(resid, [1e-3, 0.5 / l_w_mm], bounds=([0.0, 0.0], [np.inf, kappa_max]),
                        x_scale=[1e-3, 1.0 / l_w_mm])
    beta, kappa = (float(v) for v in res.x)
    err = r_gm_beam(dx, phi, beta, kappa, l_w_mm, phi_min_deg) - r
    err = np.where(np.isfinite(err), err, l_w_mm)  # an undefined estimate counts as l_w off
    rss = float(np.sum(err**2))
    ci_beta, ci_kappa = _ci(res, r.size)
    return GMFit(
        kind="beam",
        params={"beta_per_mm": beta, "kappa_per_mm": kappa},
        ci={"beta_per_mm": ci_beta, "kappa_per_mm": ci_kappa},
        rmse_mm=math.sqrt(rss / r.size),
        aic=_aic(rss, r.size, 2),
        n=int(r.size),
        l_w_mm=float(l_w_mm),
    )


def fit_gm(dx_mm, phi_deg, r_mm, l_w_mm, phi_min_deg=PHI_MIN_DEG, groups=None) -> GMFit:
    """Fit eq. (8) and the beam model; return the one with the lower AIC.

    Both fits are kept in ``alternatives`` (by kind) for the record, so the
    eq.-(8) constant C is always available. ``groups`` (run ids per sample) give
    C a run-bootstrap CI (:func:`fit_c`).
    """
    eq8 = fit_c(dx_mm, phi_deg, r_mm, l_w_mm, phi_min_deg, groups=groups)
    beam = fit_beam(dx_mm, phi_deg, r_mm, l_w_mm, phi_min_deg)
    best, other = (beam, eq8) if beam.aic < eq8.aic else (eq8, beam)
    return GMFit(**{**best.__dict__, "alternatives": {other.kind: other, best.kind: best}})
