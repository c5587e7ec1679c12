"""Moment-Force (MF) estimate of the radial contact distance, eqs. (9)-(10).

A k-nearest-neighbour look-up (k = 7) in a table of (phi, dz, r) from
calibration runs, over the normalised coordinates (phi / 35 deg, dz / 1 mm),
weighted by inverse distance.

Eq. (9) as printed is a signed sum, d_k = (phi - phi_k)/35 + (dz - dz_k)/1,
which can be zero or negative for points far away; we use the Euclidean
distance over the same normalised coordinates instead.

Defined outputs for degenerate cases:

- a query that coincides with one or more table points (distance 0) returns
  the mean r of those points (the limit of eq. (10));
- duplicate table points are fine (they are separate neighbours);
- a table with fewer than k rows uses all rows;
- NaN inputs, or phi below the table's ``phi_min_deg`` (at least
  :data:`~camwhisker.contact.gm.PHI_MIN_DEG`), give NaN;
- a query farther than :data:`MF_DOMAIN_RADIUS` from every table point is
  outside the table's domain: NaN and ``outside = True``;
- a query past the table's largest radius keeps its estimate, with
  ``past_top = True``: at its phi, dz grows with r, and a dz above the
  outermost curve's by more than half the gap to the next curve in is nearer a
  radius never calibrated than the largest one. The nearest rows all lie on
  that curve, so eq. (10) returns its radius however far beyond it the contact
  is: the estimate is a lower bound there.

The table a calibration builds (:meth:`MFTable.from_runs`) is not the pause
medians themselves but points every :data:`MF_CURVE_STEP_DEG` along each
calibration run's curve: r(phi) a cubic through the run's pauses (the contact
slides out along the bending whisker), and dz on it from one smooth surface
fitted through the pauses of every run, dz = phi^2 sum_ij c_ij (phi / 35)^i
(r / r_max)^j, i <= 3 and j <= min(3, runs - 1) (the axial force is second
order in the deflection). Pause medians lie ~2.5 deg apart along a run (0.07
in eq. (9)'s units), while neighbouring radii are 0.003-0.05 apart in dz: among
raw pause rows the k = 7 nearest are the rows of many radii at the nearest
sampled phi, at nearly equal distances, and eq. (10) returns their mean. Along
dense curves the nearest rows are those of the nearest radii. One surface, not
a polynomial per run: a run's own dz(phi) in phi^2..phi^4, fitted up to 30 deg,
misfits the simulated whisker by up to 1 um (2-3 %) at phi 3-5 deg, and at
0.4 um of dz per mm of r there that put the curves 1-5 mm short; the surface
(16 coefficients from every pause) reads the noise-free whisker back within
0.7 mm over phi 2.5-30 deg and r 25-100 mm.

Each estimate comes with MF's slope dr/d(dz) there: the neighbours' own (differences
between neighbouring radii at their phi), weighted as eq. (10) weighs their r. Times the
noise of a pause median of dz (:func:`pause_dz_noise_mm`: the calibration pauses' scatter
about the surface) it is MF's error from noise at that pause, which at one phi falls
about fivefold from r = 22 to 74 mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from camwhisker.contact.gm import PHI_MIN_DEG

__all__ = ["MF_K", "PHI_SCALE_DEG", "DZ_SCALE_MM", "MF_DOMAIN_RADIUS", "MF_CURVE_STEP_DEG",
           "MIN_CURVE_PAUSES", "MFTable", "MFResult", "r_mf", "pause_dz_noise_mm"]

MF_K = 7  # the paper's k
PHI_SCALE_DEG = 35.0  # Eq. (9): the largest expected phi
DZ_SCALE_MM = 1.0  # Eq. (9): the largest expected dz
# Normalised distance beyond which a query has no table support: 0.1 is
# 3.5 deg or 0.1 mm, more than the widest phi spacing of a calibration run
# (about 2.5 deg per 1 mm step at r = 22.5 mm) plus its noise.
MF_DOMAIN_RADIUS = 0.1
# Spacing of the table's points along each calibration run's fitted curve: under
# half the paper's per-frame phi noise (0.22 deg), 0.003 in eq. (9)'s units, about
# the dz gap between neighbouring calibration radii at phi = 5 deg.
MF_CURVE_STEP_DEG = 0.1
# Two radii closer than this (mm) are one curve when the outermost is looked for.
SAME_RADIUS_MM = 1.0
# Fewest pauses for which a run's curves are fitted (twice the 4 coefficients of
# r(phi)); a shorter run enters the table as its pause rows.
MIN_CURVE_PAUSES = 8
# Powers of the dz surface (module docstring): phi^2 (phi / PHI_SCALE_DEG)^i (r / r_max)^j.
_SURFACE_PHI_POWERS = 3
_SURFACE_R_POWERS = 3
_R_POWERS = (0, 1, 2, 3)


def _powers(x, powers):
    return np.column_stack([x**k for k in powers])


def _surface_terms(phi, r, r_max, r_powers):
    return np.column_stack([phi**2 * (phi / PHI_SCALE_DEG)**i * (r / r_max)**j
                            for i in range(_SURFACE_PHI_POWERS + 1) for j in range(r_powers + 1)])


def _dz_surface(phi, dz, r, n_runs):
    """dz(phi, r), least squares through every pause (module docstring)."""
    r_max = float(np.max(r))
    r_powers = min(_SURFACE_R_POWERS, n_runs - 1)
    coef = np.linalg.lstsq(_surface_terms(phi, r, r_max, r_powers), dz, rcond=None)[0]
    return lambda p, q: _surface_terms(p, q, r_max, r_powers) @ coef


def _runs_and_surface(phi_deg, dz_mm, r_mm, run):
    """Each run's finite rows, those long enough for curves, and the dz surface through the
    latter (None without any)."""
    run = np.asarray(run).ravel()
    phi, dz, r = (np.asarray(a, float).ravel() for a in (phi_deg, dz_mm, r_mm))
    runs = [_finite_rows(phi[run == i], dz[run == i], r[run == i]) for i in np.unique(run)]
    curved = [p for p in runs if p[0].size >= MIN_CURVE_PAUSES]
    if not curved:
        return runs, curved, None
    rows = [np.concatenate([p[j] for p in curved]) for j in range(3)]
    return runs, curved, _dz_surface(*rows, n_runs=len(curved))


def pause_dz_noise_mm(phi_deg, dz_mm, r_mm, run) -> float | None:
    """The noise of a pause median of dz: the calibration pauses' robust spread (1.4826 MAD)
    about the dz surface (module docstring). None without runs long enough for it."""
    _, curved, surface = _runs_and_surface(phi_deg, dz_mm, r_mm, run)
    if surface is None:
        return None
    e = np.concatenate([p_dz - surface(p_phi, p_r) for p_phi, p_dz, p_r in curved])
    sigma = 1.4826 * float(np.median(np.abs(e - np.median(e))))
    return sigma if sigma > 0 else None


def _run_curve(phi, r, step):
    """Points every ``step`` deg along one run's least-squares r(phi): (phi, r)."""
    a_r = np.linalg.lstsq(_powers(phi, _R_POWERS), r, rcond=None)[0]
    g = np.arange(phi.min(), phi.max() + 0.5 * step, step)
    return g, _powers(g, _R_POWERS) @ a_r


@dataclass(frozen=True)
class MFTable:
    """Labelled calibration points, arrays shape (N,), and a k-d tree over eq. (9)'s axes."""

    phi_deg: np.ndarray
    dz_mm: np.ndarray
    r_mm: np.ndarray
    tree: cKDTree = field(repr=False, compare=False, default=None)
    # Queries below this phi get no estimate (a calibration sets it where MF's scatter
    # from noise exceeds what it must detect: camwhisker.contact.calibrate.MF_MAX_SPREAD_MM).
    phi_min_deg: float = PHI_MIN_DEG
    # Per phi bin of MF_CURVE_STEP_DEG from bin phi_bin0: the dz above which a query is
    # past the outermost curve (inf where a bin has one radius only; module docstring).
    dz_past_top: np.ndarray = field(repr=False, compare=False, default=None)
    phi_bin0: int = 0
    # dr/d(dz) at each point, across the curves of its phi bin (:func:`_dr_ddz`).
    dr_ddz: np.ndarray = field(repr=False, compare=False, default=None)

    @classmethod
    def build(cls, phi_deg, dz_mm, r_mm, phi_min_deg: float = PHI_MIN_DEG) -> MFTable:
        """Keep the finite rows with phi >= PHI_MIN_DEG; raise ValueError if none remain."""
        phi, dz, r = _finite_rows(phi_deg, dz_mm, r_mm)
        if not phi.size:
            raise ValueError("MF table needs at least one row with finite phi >= "
                             f"{PHI_MIN_DEG} deg, dz and r")
        return cls(phi, dz, r, cKDTree(_coords(phi, dz)), max(PHI_MIN_DEG, float(phi_min_deg)),
                   *_past_top(phi, dz, r), _dr_ddz(phi, dz, r))

    @classmethod
    def from_runs(cls, phi_deg, dz_mm, r_mm, run, step_deg: float = MF_CURVE_STEP_DEG,
                  phi_min_deg: float = PHI_MIN_DEG) -> MFTable:
        """The table of points along each run's fitted curves (module docstring).

        ``run``: a run id per row; rows of a run need not be in order.
        """
        runs, curved, surface = _runs_and_surface(phi_deg, dz_mm, r_mm, run)
        parts = [p for p in runs if p[0].size < MIN_CURVE_PAUSES]
        for p_phi, _, p_r in curved:
            g, rg = _run_curve(p_phi, p_r, step_deg)
            parts.append((g, surface(g, rg), rg))
        if not parts:
            parts = [(np.empty(0),) * 3]
        return cls.build(*(np.concatenate([p[j] for p in parts]) for j in range(3)),
                         phi_min_deg=phi_min_deg)

    def __len__(self) -> int:
        return self.r_mm.size


def _past_top(phi, dz, r):
    """(dz_past_top, phi_bin0): per phi bin, the outermost curve's dz plus half its gap
    to the next curve in (the module docstring)."""
    b = np.round(phi / MF_CURVE_STEP_DEG).astype(int)
    b0 = int(b.min())
    out = np.full(int(b.max()) - b0 + 1, np.inf)
    for k in np.unique(b):
        rk, dk = r[b == k], dz[b == k]
        top = int(np.argmax(rk))
        inner = rk < rk[top] - SAME_RADIUS_MM
        if inner.any():
            nxt = np.flatnonzero(inner)[int(np.argmax(rk[inner]))]
            out[k - b0] = dk[top] + 0.5 * max(dk[top] - dk[nxt], 0.0)
    return out, b0


def _dr_ddz(phi, dz, r):
    """dr/d(dz) at each point: differences to the neighbouring radii of its phi bin (of
    :data:`MF_CURVE_STEP_DEG`: a calibration's curves share the bins); NaN where a bin holds
    one radius or dz does not grow with r there."""
    b = np.round(phi / MF_CURVE_STEP_DEG).astype(int)
    out = np.full(r.size, np.nan)
    for k in np.unique(b):
        idx = np.flatnonzero(b == k)
        if idx.size < 2:
            continue
        idx = idx[np.argsort(r[idx])]
        with np.errstate(divide="ignore", invalid="ignore"):
            g = np.gradient(r[idx], dz[idx])
        out[idx] = np.where(np.isfinite(g) & (g > 0), g, np.nan)
    return out


def _finite_rows(phi_deg, dz_mm, r_mm):
    phi, dz, r = (np.asarray(a, float).ravel() for a in (phi_deg, dz_mm, r_mm))
    keep = np.isfinite(phi) & np.isfinite(dz) & np.isfinite(r) & (phi >= PHI_MIN_DEG)
    return phi[keep], dz[keep], r[keep]


def _coords(phi_deg, dz_mm):
    return np.column_stack([np.asarray(phi_deg, float) / PHI_SCALE_DEG,
                            np.asarray(dz_mm, float) / DZ_SCALE_MM])


@dataclass(frozen=True)
class MFResult:
    """r_MF (NaN where undefined), the out-of-domain flag, the nearest distance and the
    past-the-largest-radius flag (r_MF a lower bound), and dr/d(dz) there (mm of r per mm of
    dz: what a pause's dz noise makes of r_MF; NaN where the table gives none)."""

    r_mm: np.ndarray
    outside: np.ndarray
    nearest: np.ndarray
    past_top: np.ndarray
    dr_ddz: np.ndarray


def r_mf(table: MFTable, phi_deg, dz_mm, k: int = MF_K,
         domain_radius: float = MF_DOMAIN_RADIUS) -> MFResult:
    """Inverse-distance-weighted kNN estimate of r, eqs. (9)-(10).

    Parameters
    ----------
    table : MFTable
    phi_deg, dz_mm : array_like, shape (N,)
    k : int
        Neighbours (the paper: 7); fewer if the table is smaller.
    domain_radius : float
        Normalised distance beyond which a query is outside the table.
    """
    phi = np.atleast_1d(np.asarray(phi_deg, float))
    dz = np.atleast_1d(np.asarray(dz_mm, float))
    kk = min(k, len(table))
    if phi.size == 1 and dz.size == 1:  # the live loop's one row: no output arrays to fill
        p, q = phi.item(), dz.item()
        if not (kk >= 1 and math.isfinite(p) and math.isfinite(q) and p >= table.phi_min_deg):
            return MFResult(np.full(1, np.nan), np.zeros(1, bool), np.full(1, np.nan),
                            np.zeros(1, bool), np.full(1, np.nan))
        if kk < _SUMMED_IN_ORDER:
            return MFResult(*(np.array([v]) for v in _knn_one(table, p, q, kk, domain_radius)))
        return MFResult(*_knn(table, phi, dz, kk, domain_radius))
    phi, dz = np.broadcast_arrays(phi, dz)
    n = phi.size
    r_out = np.full(n, np.nan)
    outside = np.zeros(n, bool)
    nearest = np.full(n, np.nan)
    past_top = np.zeros(n, bool)
    dr_ddz = np.full(n, np.nan)
    valid = np.isfinite(phi) & np.isfinite(dz) & (phi >= table.phi_min_deg)
    if not valid.any() or kk < 1:
        return MFResult(r_out, outside, nearest, past_top, dr_ddz)
    r_out[valid], outside[valid], nearest[valid], past_top[valid], dr_ddz[valid] = _knn(
        table, phi[valid], dz[valid], kk, domain_radius)
    return MFResult(r_out, outside, nearest, past_top, dr_ddz)


# numpy sums fewer terms than this one after another (its pairwise sum starts at 8), as a
# Python loop does: below it, one query's eq. (10) in Python floats gives the same bits.
_SUMMED_IN_ORDER = 8


def _sum_in_order(values) -> float:
    total = 0.0
    for v in values:
        total += v
    return total


def _knn_one(table: MFTable, phi: float, dz: float, kk: int, domain_radius: float):
    """:func:`_knn` of one query in Python floats (kk < _SUMMED_IN_ORDER): the same
    operations in the same order, so the same bits, without numpy's per-call overhead."""
    d, j = table.tree.query((phi / PHI_SCALE_DEG, dz / DZ_SCALE_MM), k=kk)  # Eq. (9)
    d, j = np.atleast_1d(d).tolist(), np.atleast_1d(j)
    labels, g = table.r_mm[j].tolist(), table.dr_ddz[j].tolist()
    if 0.0 in d:
        w = [float(x == 0.0) for x in d]
    else:
        w = [1.0 / x for x in d]
    est = _sum_in_order(a * b for a, b in zip(w, labels, strict=True)) / _sum_in_order(w)  # (10)
    wg = [a if math.isfinite(b) else 0.0 for a, b in zip(w, g, strict=True)]
    wg_sum = _sum_in_order(wg)
    slope = (_sum_in_order(a * (b if math.isfinite(b) else 0.0) for a, b in zip(wg, g, strict=True))
             / wg_sum if wg_sum > 0 else math.nan)
    near = d[0]
    phi_bin = min(max(round(phi / MF_CURVE_STEP_DEG) - table.phi_bin0, 0),
                  table.dz_past_top.size - 1)
    out = near > domain_radius
    return (math.nan if out else est, out, near,
            not out and bool(dz > table.dz_past_top[phi_bin]), math.nan if out else slope)


def _knn(table: MFTable, phi, dz, kk: int, domain_radius: float):
    """Eqs. (9)-(10) for queries with finite phi >= the table's floor and dz, arrays shape
    (M,): (r_mm, outside, nearest, past_top, dr_ddz) as :class:`MFResult` holds them."""
    d, j = table.tree.query(_coords(phi, dz), k=kk)  # Eq. (9), Euclidean
    d = d.reshape(-1, kk)
    j = j.reshape(-1, kk)
    labels = table.r_mm[j]
    exact = d == 0.0
    any_exact = exact.any(axis=1)
    w = np.divide(1.0, d, out=np.zeros_like(d), where=~exact)
    if any_exact.any():
        w = np.where(any_exact[:, None], exact.astype(float), w)
    est = np.add.reduce(w * labels, axis=1) / np.add.reduce(w, axis=1)  # Eq. (10)
    # The neighbours' dr/d(dz), weighted as eq. (10) weighs their r.
    g = table.dr_ddz[j]
    finite = np.isfinite(g)
    wg = np.where(finite, w, 0.0)
    wg_sum = np.add.reduce(wg, axis=1)
    slope = np.divide(np.add.reduce(wg * np.where(finite, g, 0.0), axis=1), wg_sum,
                      out=np.full(est.shape, np.nan), where=wg_sum > 0)
    near = d[:, 0]
    # np.clip's Python wrapper costs more than the rest of a live row's look-up.
    phi_bin = np.minimum(np.maximum(np.round(phi / MF_CURVE_STEP_DEG).astype(int)
                                    - table.phi_bin0, 0), table.dz_past_top.size - 1)
    out = near > domain_radius
    return (np.where(out, np.nan, est), out, near, ~out & (dz > table.dz_past_top[phi_bin]),
            np.where(out, np.nan, slope))
