"""Clock offset between a stage log and a signal table from continuous motion.

The whisker is quasi-static: phi (and dz) are a function of the base position
alone, phi(t) = f(x(t - offset_s)), whatever the base does (pauses or not).
For a trial offset every frame gets the base position at its stage time, a
penalised linear spline in x (knots every :data:`KNOT_MM`, a small
second-difference penalty so that knots without frames stay defined) is
fitted to the signal by least squares, and the residual sum of squares in
units of the signal's own noise is the cost. A wrong offset maps frames of
different phi to one x (where the base stops, turns or changes speed) and the
fit fails there. Same convention as :mod:`camwhisker.contact.stage`:

    t_camera = t_stage + offset_s.

That cost is flat for an offset that makes the base stop later than it did:
phi levelling off looks like a function of x too. So the minimum on a coarse,
then a fine grid only brackets the offset; near every change of the base's
speed (:func:`motion_events`) f is then fitted as a line in x, in windows of
the camera signal fixed around the event (first 2 s, then 3 mm of travel
either side), and the summed chi-square is minimised over the offset. A
parabola through it near its minimum gives the estimate and, as for any
least-squares fit of one parameter, its standard error 1 / sqrt(a) from the
chi-square's curvature a. A sweep at constant speed is pinned by its stop
alone: a slow one is as good as the noise over the stop allows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve

from camwhisker.contact.stage import StageLog

__all__ = ["OffsetEstimate", "estimate_offset_motion", "motion_events", "noise_sd"]

# Knot spacing of f(x): half the simulator's 1 mm step, finer than phi's curvature.
KNOT_MM = 0.5
# Second-difference penalty per knot, relative to the frames per knot: it only
# bridges knots without frames and costs < 1 % of the fit's freedom elsewhere.
SMOOTH = 1e-2
# Ridge toward 0, relative to the frames per knot: far below any signal's weight.
RIDGE = 1e-6
COARSE_STEP_S = 0.1
# Fine grid: 4 ms, an eighth of a frame at 30 frames/s.
FINE_STEP_S = 0.004
# Coarse local minima refined on the fine grid: the true one can score worse on
# the coarse grid (up to half a step off) than a shift by whole features.
CANDIDATES = 3
# A change of the base's speed larger than this (mm/s) is an event: far above a
# stage's speed ripple, far below the slowest sweep (0.5 mm/s).
EVENT_DV_MM_S = 0.05
# The spline step can be late by up to ~1 s (the time a wrong stop looks like a
# levelling off); the refinement searches this far either side of it.
REFINE_S = 1.5
# ... and this far after it (a few frames: its error the other way is that small).
REFINE_MARGIN_S = 0.2
# Half-window (s) around each event in which f(x) is linear: covers the search.
WINDOW_S = 2.0
# Half-window of the second pass in base travel (mm); it searches half of it either side.
SHORT_WINDOW_MM = 3.0
# ... but never shorter than this (s): the first pass is good to about a tenth of it.
SHORT_WINDOW_MIN_S = 0.3
# Half-width (s) of the parabola fitted around the fine minimum.
PARABOLA_HALF_S = 0.05


@dataclass(frozen=True)
class OffsetEstimate:
    """offset_s (NaN: not determined), its standard error (s) and the explained share."""

    offset_s: float
    se_s: float
    score: float

    def __bool__(self) -> bool:
        return math.isfinite(self.offset_s)


def noise_sd(signal) -> float:
    """Per-sample noise sd from first differences (robust: median absolute difference)."""
    v = np.asarray(signal, float)
    d = np.diff(v)
    d = d[np.isfinite(d)]
    if d.size < 2:
        return math.nan
    # A difference of two noisy samples has sd sqrt(2) sigma; MAD / 0.6745 = sd for Gaussians.
    return float(np.median(np.abs(d - np.median(d))) / 0.6745 / math.sqrt(2.0))


class _SplineCost:
    """chi-square of the best f(x) for one signal, as a function of the offset."""

    def __init__(self, log: StageLog, t_camera_s, signal):
        self.log = log
        self.t = np.asarray(t_camera_s, float)
        self.y = np.asarray(signal, float)
        finite = np.isfinite(self.y) & np.isfinite(self.t)
        self.finite = finite
        self.t, self.y = self.t[finite], self.y[finite]
        sd = noise_sd(signal)
        self.var = sd * sd if sd > 0 else np.var(self.y) or 1.0
        self.total = float(np.sum((self.y - self.y.mean()) ** 2))
        lo, hi = float(np.min(log.x_mm)), float(np.max(log.x_mm))
        self.x_lo = lo
        self.k = max(int(math.ceil((hi - lo) / KNOT_MM)), 1) + 1
        d2 = np.diff(np.eye(self.k), 2, axis=0)
        per_knot = max(self.y.size / self.k, 1.0)
        # A tiny ridge keeps the system definite when the frames cover one or two knots.
        self.penalty = per_knot * (SMOOTH * (d2.T @ d2) + RIDGE * np.eye(self.k))

    def rss(self, offset_s: float) -> float:
        x = self.log.x_at(self.t - offset_s)
        inside = np.isfinite(x)
        y = self.y[inside]
        # Frames the offset puts outside the log are not explained: full deviation.
        outside = float(np.sum((self.y[~inside] - self.y.mean()) ** 2))
        if y.size < 3:
            return self.total
        u = (x[inside] - self.x_lo) / KNOT_MM
        j = np.clip(np.floor(u).astype(int), 0, self.k - 2)
        w = u - j
        a = 1.0 - w
        k = self.k
        # Normal equations of the hat basis: tridiagonal B^T B, from bincounts.
        diag = np.bincount(j, a * a, k) + np.bincount(j + 1, w * w, k)
        off = np.bincount(j, a * w, k - 1)
        btb = self.penalty + np.diag(diag) + np.diag(off, 1) + np.diag(off, -1)
        bty = np.bincount(j, a * y, k) + np.bincount(j + 1, w * y, k)
        c = solve(btb, bty, assume_a="pos")
        r = y - (a * c[j] + w * c[j + 1])
        return float(r @ r) + outside

    def mask(self, per_frame):
        """A per-frame array (or None) cut to this signal's finite frames."""
        return None if per_frame is None else np.asarray(per_frame, bool)[self.finite]

    def chi2(self, offset_s: float) -> float:
        return self.rss(offset_s) / self.var


def _velocity(log: StageLog) -> np.ndarray:
    """The base's velocity per interval (mm/s): (N - 1,) along x, or (N - 1, k) in 3-D."""
    if log.motion_mm is None:
        return np.diff(log.x_mm) / np.diff(log.t_s)
    return log.motion_mm / np.diff(log.t_s)[:, None]


def _size(v: np.ndarray) -> np.ndarray:
    """|v| per row: a speed along x, or a 3-D velocity's norm."""
    return np.abs(v) if v.ndim == 1 else np.linalg.norm(v, axis=1)


def motion_events(log: StageLog) -> np.ndarray:
    """Stage times (s) where the base's speed changes: starts, stops, changes of speed
    (in 3-D with the log's ``motion_mm``: a turn of its direction too)."""
    v = _velocity(log)
    change = _size(np.diff(v, axis=0)) > EVENT_DV_MM_S
    idx = np.flatnonzero(change) + 1
    if idx.size == 0:
        return np.empty(0)
    # A change that spans neighbouring samples is one event: the middle of the run.
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    return np.array([0.5 * (log.t_s[r[0]] + log.t_s[r[-1]]) for r in runs])


def event_speeds(log: StageLog, events) -> np.ndarray:
    """The base's larger speed (mm/s) either side of each event, one stage sample away."""
    v = _size(_velocity(log))
    out = []
    for tau in np.atleast_1d(events):
        k = np.searchsorted(log.t_s, tau)
        out.append(max(v[max(k - 2, 0)], v[min(k + 1, v.size - 1)]))
    return np.array(out)


def _local_chi2(log: StageLog, t, y, var, events, offset0, offsets, half_s, contact=None):
    """chi-square of a line f(x) fitted in a window around each event, per trial offset.

    ``half_s``: the window's half-width (s), one value or one per event. The
    frames of each window are fixed (camera time around event + offset0), so
    every trial offset is scored on the same frames. ``contact`` (bool per
    frame, optional): a window counts only if every frame in it is in contact.
    """
    halves = np.broadcast_to(np.asarray(half_s, float), np.shape(events))
    out = np.zeros(offsets.size)
    dof = 0
    for tau, half in zip(events, halves, strict=True):
        w = np.abs(t - (tau + offset0)) <= half
        if w.sum() < 8 or (contact is not None and not contact[w].all()):
            continue
        dof += int(w.sum()) - 2
        yw = y[w]
        x = log.x_at(t[w][None, :] - offsets[:, None])  # shape (n_offsets, n_frames)
        x = x - np.nanmean(x)
        valid = np.isfinite(x).all(axis=1)
        x = np.nan_to_num(x)
        basis = np.stack([np.ones_like(x), x], axis=2)  # (n_off, n, 2)
        ata = np.einsum("oni,onj->oij", basis, basis) + 1e-9 * np.eye(2)
        aty = np.einsum("oni,n->oi", basis, yw)
        coef = np.linalg.solve(ata, aty[..., None])[..., 0]
        r = yw[None, :] - np.einsum("oni,oi->on", basis, coef)
        out += np.where(valid, np.sum(r * r, axis=1), np.sum((yw - yw.mean()) ** 2)) / var
    return out, dof


def _spline_offset(costs: list, search_s: tuple[float, float]) -> float:
    """The offset minimising the spline fits' summed chi-square: a coarse grid, then a
    fine one around its best few local minima."""

    def chi2(o):
        return sum(c.chi2(o) for c in costs)

    lo, hi = search_s
    coarse = np.arange(lo, hi + COARSE_STEP_S / 2, COARSE_STEP_S)
    cs = np.array([chi2(o) for o in coarse])
    local = np.r_[True, cs[1:] <= cs[:-1]] & np.r_[cs[:-1] <= cs[1:], True]
    peaks = np.flatnonzero(local)
    peaks = peaks[np.argsort(cs[peaks])[:CANDIDATES]]
    best_o, best_c = None, None
    for b in coarse[peaks]:
        fine = np.arange(b - 1.5 * COARSE_STEP_S, b + 1.5 * COARSE_STEP_S, FINE_STEP_S)
        fc = np.array([chi2(o) for o in fine])
        if best_c is None or fc.min() < best_c.min():
            best_o, best_c = fine, fc
    return float(best_o[int(np.argmin(best_c))])


def estimate_offset_motion(log: StageLog, t_camera_s, signals,
                           search_s: tuple[float, float] = (-30.0, 30.0),
                           in_contact=None) -> OffsetEstimate:
    """Estimate ``offset_s`` (t_camera = t_stage + offset_s) from signals that follow x.

    Two steps. The global spline fit of f(x) (module docstring) finds the offset
    to within the time the base runs after its last change of speed: a later
    stop only looks like phi levelling off. Then, in a window of
    :data:`WINDOW_S` around every change of the base's speed, f is fitted as a
    line in x (phi is smooth in x over a few mm, a kink in it is not) and
    the summed chi-square is minimised over the offset near the first estimate.

    Parameters
    ----------
    log : StageLog
    t_camera_s : ndarray, shape (N,)
    signals : sequence of ndarray, shape (N,)
        phi_deg (and dz_mm): NaN where untrusted. Their chi-squares add.
    search_s : (float, float)
    in_contact : ndarray of bool, shape (N,), optional
        Frames in contact. An event then counts only where the whisker is in
        contact throughout its window: contact starting or ending there is a kink
        in f(x) that the line reads as an offset; out of contact f is flat.

    Returns
    -------
    OffsetEstimate
        Falsy (offset NaN) when the signals do not vary with x (explained share
        below 0.5: no contact seen) or the log holds one position only. Its se is
        NaN where no event counts (a sweep at one speed whose contact starts and
        ends inside it): the offset is the spline fit's alone and not pinned; any
        offset then shifts every frame's x alike, and GM's dx does not change.
    """
    if np.ptp(log.x_mm) <= 0:
        return OffsetEstimate(math.nan, math.nan, 0.0)
    costs = [_SplineCost(log, t_camera_s, s) for s in signals]
    costs = [c for c in costs if c.y.size >= 3]
    if not costs:
        return OffsetEstimate(math.nan, math.nan, 0.0)

    first = _spline_offset(costs, search_s)
    explained = float(np.mean([1.0 - c.rss(first) / c.total if c.total > 0 else 0.0
                               for c in costs]))
    if explained < 0.5:
        return OffsetEstimate(math.nan, math.nan, explained)
    events = motion_events(log)
    # The spline's error is one-sided (late): search mostly before its estimate.
    grid = np.arange(first - REFINE_S, first + REFINE_MARGIN_S, FINE_STEP_S)
    lc = sum(_local_chi2(log, c.t, c.y, c.var, events, first - 0.5 * REFINE_S, grid, WINDOW_S,
                         c.mask(in_contact))[0] for c in costs)  # fmt: skip
    if not np.any(lc > 0):
        return OffsetEstimate(first, math.nan, explained)
    # Second pass in windows of a fixed travel: little of phi's curvature in x to bias
    # the line, and as many frames as that travel gives at the event's speed.
    second = float(grid[int(np.argmin(lc))])
    half = np.clip(SHORT_WINDOW_MM / np.maximum(event_speeds(log, events), 1e-9),
                   SHORT_WINDOW_MIN_S, WINDOW_S)
    reach = 0.5 * float(np.min(half))
    grid = np.arange(second - reach, second + reach, FINE_STEP_S)
    parts = [_local_chi2(log, c.t, c.y, c.var, events, second, grid, half, c.mask(in_contact))
             for c in costs]  # fmt: skip
    lc = sum(p[0] for p in parts)
    dof = sum(p[1] for p in parts)
    if dof <= 0:  # no event window wholly in contact at this width
        return OffsetEstimate(second, math.nan, explained)
    i = int(np.argmin(lc))
    near = np.abs(grid - grid[i]) <= PARABOLA_HALF_S
    a2, a1, _ = np.polyfit(grid[near] - grid[i], lc[near], 2)
    if a2 > 0 and abs(a1 / (2 * a2)) <= PARABOLA_HALF_S:
        # A line that misfits (phi's own kinks near the event) widens the se by the
        # reduced chi-square, as for any least-squares fit whose model is short.
        inflate = max(float(lc[i]) / dof, 1.0) if dof > 0 else 1.0
        offset, se = grid[i] - a1 / (2 * a2), math.sqrt(inflate / a2)
    else:
        offset, se = grid[i], math.nan
    return OffsetEstimate(float(offset), float(se), explained)
