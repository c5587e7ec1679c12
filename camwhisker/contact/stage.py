"""Linear-stage logs: parse and validate, find pauses, estimate the clock offset, pause medians.

A stage log (docs/sensor.md section 7) is a CSV with header ``t_s,x_mm`` and an
optional ``r_mm`` (known contact distance) and ``dz_mm`` (applied axial
deflection), on the stage's own clock. The camera's signal table
(section 6) has its own clock; ``offset_s`` below always means

    t_camera = t_stage + offset_s.

The paper takes, for every pause of the stage (stationary >= 1 s), the median
of phi and dz over the frames of the pause; :func:`pause_medians` does that.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camwhisker.files.tables import read_log
from camwhisker.io.bag import STAGE_TYPES, bag_source, read_bag_poses

__all__ = [
    "StageLogError",
    "StageLog",
    "Pauses",
    "PauseTable",
    "read_stage_log",
    "stage_log_from_arrays",
    "detect_pauses",
    "estimate_offset",
    "best_offset",
    "pause_medians",
    "pause_index",
    "pause_frames",
    "log_pause_medians",
    "contact_onset_x",
    "MIN_PAUSE_S",
]

# The paper: "We ensured at least one second between steps."
MIN_PAUSE_S = 1.0
# Position changes below this count as standing still: the NRT-150's 0.1 um
# resolution is far finer; 1 um also absorbs a printed rounding of x_mm.
STATIONARY_TOL_MM = 1e-3
# Frames this close to either end of a pause are left out of its median: it
# covers a residual clock-offset error and the settling of a quasi-static step.
PAUSE_TRIM_S = 0.1
# A pause needs this many trusted frames to give a median: three is the fewest
# whose median still rejects one bad frame, and what a 1.2 s pause holds at a
# low recording rate of 3 frames/s (at 30 frames/s a pause holds 30 or more).
MIN_PAUSE_FRAMES = 3
# Offset search: coarse grid then a fine grid around the best coarse value.
OFFSET_COARSE_STEP_S = 0.1
OFFSET_FINE_STEP_S = 0.004
# Coarse local maxima refined on the fine grid (the best refined one wins).
OFFSET_CANDIDATES = 3
# Default search range of the offset (+-, s); a caller that knows better passes search_s.
DEFAULT_OFFSET_RANGE_S = 30.0
# Scores within this of the best count as the best plateau: about the score's
# noise from one frame's worth of noise moving in or out of a pause.
OFFSET_PLATEAU = 1e-4
# Trial offsets are scored in blocks of about this many (offset, frame) pairs: a block's
# temporaries (128 kB each) stay in the CPU's cache; four times larger ran 1.6x slower.
SCORE_CHUNK = 1 << 14


class StageLogError(ValueError):
    """A stage log that cannot be used; the message names the file, row and problem."""


@dataclass(frozen=True)
class StageLog:
    """A validated stage log: arrays of shape (N,), times strictly increasing."""

    t_s: np.ndarray
    x_mm: np.ndarray
    r_mm: np.ndarray | None
    source: str
    dz_mm: np.ndarray | None = None
    # The base's motion per interval (N - 1, k) in mm where it moves in more than x (a
    # pose log's base in 3-D): its pauses and changes of speed are found from it.
    motion_mm: np.ndarray | None = None

    @property
    def travel_sign(self) -> float:
        """+1 if the stage travels toward +x over the log, -1 if toward -x."""
        return 1.0 if self.x_mm[-1] >= self.x_mm[0] else -1.0

    def x_at(self, t_stage_s) -> np.ndarray:
        """Stage position at stage-clock times; NaN outside the log."""
        t = np.asarray(t_stage_s, float)
        return np.interp(t, self.t_s, self.x_mm, left=np.nan, right=np.nan)


def read_stage_log(path: str | Path, max_gap_s: float = MIN_PAUSE_S) -> StageLog:
    """Read and validate a stage log CSV.

    Parameters
    ----------
    path : str or Path
    max_gap_s : float
        Largest allowed interval between consecutive samples; a longer gap
        could hide a motion, so it is an error.

    ``path`` may name a topic of an MCAP bag, ``FILE.mcap:/topic`` (the extra ``ros``), of
    ROS 2 PointStamped, PoseStamped or TransformStamped messages: x_mm is the position's x
    (metres there), t_s the header's stamp; rows are the topic's messages counted from 1.

    Raises
    ------
    StageLogError
        Missing file or columns, a non-numeric or non-finite cell, times not
        strictly increasing (unsorted or duplicate), a gap, or fewer than two rows.
        The message names the file and the 1-based row (the header is row 1); for a
        bag, ``FILE:TOPIC`` (a missing topic lists the bag's).
    """
    bag = bag_source(path, StageLogError)
    if bag is not None:
        t, p_mm, _ = read_bag_poses(*bag, STAGE_TYPES, StageLogError)
        return stage_log_from_arrays(t, p_mm[:, 0], source=f"{bag[0]}:{bag[1]}",
                                     max_gap_s=max_gap_s, first_row=1)  # fmt: skip
    path = Path(path)
    arrays, _ = read_log(path, ("t_s", "x_mm"), ("r_mm", "dz_mm"), "stage log", StageLogError)
    return stage_log_from_arrays(arrays["t_s"], arrays["x_mm"], arrays.get("r_mm"),
                                 source=str(path), max_gap_s=max_gap_s, first_row=2,
                                 dz_mm=arrays.get("dz_mm"))


def stage_log_from_arrays(t_s, x_mm, r_mm=None, source="<arrays>", max_gap_s=MIN_PAUSE_S,
                          first_row=0, dz_mm=None, motion_mm=None) -> StageLog:
    """Validate arrays as a stage log (see :func:`read_stage_log`); rows counted from first_row.

    ``motion_mm`` (N - 1, k), optional: the base's motion per interval where x is only its
    projection (:attr:`StageLog.motion_mm`)."""
    t = np.asarray(t_s, float)
    x = np.asarray(x_mm, float)
    if t.size < 2:
        raise StageLogError(f"{source}: needs at least 2 samples, got {t.size}")
    if x.shape != t.shape or any(v is not None and np.shape(v) != t.shape for v in (r_mm, dz_mm)):
        raise StageLogError(f"{source}: columns have different lengths")
    for name, v in (("t_s", t), ("x_mm", x)):
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            raise StageLogError(f"{source}: row {bad[0] + first_row}: {name} is not finite")
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        k = bad[0]
        what = "duplicate time" if dt[k] == 0 else "time goes backwards (unsorted)"
        raise StageLogError(
            f"{source}: row {k + 1 + first_row}: {what}: t_s = {float(t[k + 1])!r} "
            f"after {float(t[k])!r}"
        )
    gap = np.flatnonzero(dt > max_gap_s)
    if gap.size:
        k = gap[0]
        raise StageLogError(
            f"{source}: row {k + 1 + first_row}: gap of {dt[k]:.3f} s after t_s = {float(t[k])!r} "
            f"(more than {max_gap_s} s without a sample)"
        )
    r = None if r_mm is None else np.asarray(r_mm, float)
    dz = None if dz_mm is None else np.asarray(dz_mm, float)
    motion = None if motion_mm is None else np.asarray(motion_mm, float).reshape(t.size - 1, -1)
    return StageLog(t_s=t, x_mm=x, r_mm=r, source=source, dz_mm=dz, motion_mm=motion)


@dataclass(frozen=True)
class Pauses:
    """Stationary intervals of a stage log (stage clock), arrays shape (P,)."""

    t_start_s: np.ndarray
    t_end_s: np.ndarray
    x_mm: np.ndarray


def detect_pauses(log: StageLog, min_pause_s: float = MIN_PAUSE_S,
                  tol_mm: float = STATIONARY_TOL_MM) -> Pauses:
    """Intervals where the stage stands still for at least ``min_pause_s``.

    Consecutive samples closer than ``tol_mm`` belong to the same stationary run;
    a run's duration is from its first to its last sample. With the log's ``motion_mm``
    the base stands still where that motion is under ``tol_mm``, not only x.
    """
    if log.motion_mm is None:
        moving = np.abs(np.diff(log.x_mm)) > tol_mm
    else:
        moving = np.linalg.norm(log.motion_mm, axis=1) > tol_mm
    # Run boundaries: a new run starts after every moving interval.
    starts, ends = [], []
    i = 0
    n = log.t_s.size
    while i < n:
        j = i
        while j < n - 1 and not moving[j]:
            j += 1
        starts.append(i)
        ends.append(j)
        i = j + 1
    s, e = np.array(starts), np.array(ends)
    keep = (log.t_s[e] - log.t_s[s]) >= min_pause_s
    s, e = s[keep], e[keep]
    return Pauses(t_start_s=log.t_s[s], t_end_s=log.t_s[e], x_mm=log.x_mm[s])


def pause_index(t_camera_s, pauses: Pauses, offset_s: float, trim_s: float):
    """Index of the pause each camera time falls in (-1 for none), ``trim_s`` in from each end."""
    t_stage = np.asarray(t_camera_s, float) - offset_s
    if pauses.t_start_s.size == 0:  # a log that never stands still for a pause
        return np.full(t_stage.shape, -1)
    k = np.searchsorted(pauses.t_start_s + trim_s, t_stage, side="right") - 1
    kc = np.clip(k, 0, None)
    inside = (k >= 0) & (t_stage <= pauses.t_end_s[kc] - trim_s) & np.isfinite(t_stage)
    return np.where(inside, k, -1)


def pause_frames(t_camera_s, good, pauses: Pauses, offset_s: float) -> list[np.ndarray]:
    """Indices of the ``good`` frames in each pause, :data:`PAUSE_TRIM_S` in from either end."""
    idx = pause_index(t_camera_s, pauses, offset_s, PAUSE_TRIM_S)
    order = np.argsort(idx, kind="stable")
    bounds = np.searchsorted(idx[order], np.arange(pauses.t_start_s.size + 1))
    good = np.asarray(good, bool)
    return [f[good[f]] for f in (order[a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True))]


def log_pause_medians(log: StageLog, values, pauses: Pauses) -> np.ndarray:
    """Median of a log column (r_mm, dz_mm) over the samples of each pause; NaN without it."""
    out = np.full(pauses.t_start_s.size, np.nan)
    if values is None:
        return out
    for k, (a, b) in enumerate(zip(pauses.t_start_s, pauses.t_end_s, strict=True)):
        out[k] = np.median(values[(log.t_s >= a) & (log.t_s <= b)])
    return out


def _explained(signals, first, last, stage_x, pause_x) -> np.ndarray:
    """Share of each signal's variance explained by the quasi-static model, per trial offset.

    The model: the signal is a function of the stage position only, equal to
    its pause mean at each pause position and linear in x between them (so the
    frames of a step's ramp are predicted too). Frames outside the log are
    unexplained. NaN-free result in [-inf, 1].

    ``signals``: (S, n). A row per trial offset: frames ``first[i, p]`` up to
    ``last[i, p]`` (k, P) are pause p's; ``stage_x(a, b)`` is every frame's stage
    position (b - a, n) at trial offsets a to b. Returns (S, k).
    """
    k, p = first.shape
    order = np.argsort(pause_x, kind="stable")
    xp, first, last = pause_x[order], first[:, order], last[:, order]
    out = np.zeros((len(signals), k))
    fits = [_pause_fit(signal, first, last, xp) for signal in signals]
    rows = max(1, SCORE_CHUNK // max(signals[0].size, 1))
    for a in range(0, k, rows):
        b = min(a + rows, k)
        x = stage_x(a, b)
        # Each frame's piece of the model: its row's, by the pauses at or below its x.
        cell = np.searchsorted(xp, x, side="right") + (p + 1) * np.arange(a, b)[:, None]
        inside = np.isfinite(x)
        for j, (signal, finite, dev2, total, ok, x0, y0, slope) in enumerate(fits):
            if total <= 0.0:
                continue
            use = inside & finite
            model = slope.take(cell) * (x - x0.take(cell)) + y0.take(cell)
            # Frames that the offset puts outside the log are not explained: they count
            # with their full deviation, so an offset that slides most of the signal off
            # the log cannot score high on the few frames left.
            err = np.where(use, (signal - model) ** 2, dev2).sum(axis=1)
            fit = ok[a:b] & (np.count_nonzero(use, axis=1) >= 2 * MIN_PAUSE_FRAMES)
            out[j, a:b] = np.where(fit, 1.0 - err / total, 0.0)
    return out


def _pause_fit(signal, first, last, xp):
    """One signal's terms of :func:`_explained`: its finite frames, squared deviations from
    its mean and their sum, the offsets with enough pause frames, and the model's pieces
    (x0, y0, slope flattened, :func:`_segments`) from its pause means."""
    finite = np.isfinite(signal)
    count = np.concatenate(([0], np.cumsum(finite)))
    count = count[last] - count[first]
    ok = count.sum(axis=1) >= 2 * MIN_PAUSE_FRAMES
    dev2 = np.zeros(signal.shape)
    total = 0.0
    if ok.any():
        dev2[finite] = (signal[finite] - signal[finite].mean()) ** 2
        total = float(np.sum(dev2[finite]))
    # Pause means from running sums: a pause's frames are a range of the time-ordered ones.
    cum = np.concatenate(([0.0], np.cumsum(np.where(finite, signal, 0.0))))
    level = np.divide(cum[last] - cum[first], count, out=np.full(count.shape, np.nan),
                      where=count > 0)
    return (signal, finite, dev2, total, ok, *(v.ravel() for v in _segments(xp, level)))


def _segments(xp, fp):
    """np.interp's line pieces over each row's finite levels ``fp`` (k, p) at sorted ``xp``:
    x0, y0 and slope (k, p + 1) for x with 0..p of xp at or below it, so that
    ``slope * (x - x0) + y0`` is ``np.interp(x, xp, fp[i])`` to the bit: the ends held
    flat, else the piece from the last level at or below x to the next."""
    k, p = fp.shape
    have = np.isfinite(fp)
    cols = np.arange(p + 1)
    none, every = np.zeros((k, 1), bool), np.ones((k, 1), bool)
    # The last level among the first j pauses (lo, -1 for none), the first after (hi, p).
    lo = np.maximum.accumulate(np.where(np.hstack((none, have)), cols - 1, -1), axis=1)
    hi = np.minimum.accumulate(np.where(np.hstack((have, every)), cols, p)[:, ::-1],
                               axis=1)[:, ::-1]
    flat = (lo < 0) | (hi >= p)
    # A row without levels points anywhere: its score is 0 (too few pause frames).
    lo = np.minimum(np.where(lo < 0, hi, lo), p - 1)
    hi = np.where(flat, lo, hi)
    rows = np.arange(k)[:, None]
    x0, y0 = xp[lo], fp[rows, lo]
    # Pauses at one x (a turning run's) make pieces of no width: no x looks them up.
    with np.errstate(divide="ignore", invalid="ignore"):
        return x0, y0, (fp[rows, hi] - y0) / np.where(flat, 1.0, xp[hi] - x0)


def _first_frame(t, offsets, bounds, after: bool) -> np.ndarray:
    """Per trial offset (k, 1) and bound (P,): the first frame whose stage time t - offset
    is past the bound (``after``: beyond it, else at or beyond); t sorted, NaN last.

    Decided on t - offset itself, as a frame's stage time is everywhere else (the
    search on t against bound + offset may be a rounding off at a tie)."""
    n = t.size
    i = np.searchsorted(t, bounds + offsets, side="right" if after else "left")
    past = np.greater if after else np.greater_equal
    while (back := (i > 0) & past(t[np.maximum(i - 1, 0)] - offsets, bounds)).any():
        i = i - back
    while (ahead := (i < n) & ~past(t[np.minimum(i, n - 1)] - offsets, bounds)
           & np.isfinite(t[np.minimum(i, n - 1)])).any():
        i = i + ahead
    return i


def _offset_scores(log: StageLog, pauses: Pauses, t, signals, offsets) -> np.ndarray:
    """The mean explained share of the signals for each trial offset (s) of a 1-D array;
    the frames' camera times ``t`` sorted, NaN last."""
    o = np.asarray(offsets, float)[:, None]
    first = _first_frame(t, o, pauses.t_start_s + PAUSE_TRIM_S, after=False)
    last = np.maximum(_first_frame(t, o, pauses.t_end_s - PAUSE_TRIM_S, after=True), first)
    shares = _explained(signals, first, last, lambda a, b: log.x_at(t - o[a:b]), pauses.x_mm)
    return np.mean(shares, axis=0)


def estimate_offset(log: StageLog, t_camera_s, phi_deg, dz_mm=None,
                    search_s: tuple[float, float] = (-DEFAULT_OFFSET_RANGE_S,
                                                     DEFAULT_OFFSET_RANGE_S)):
    """Estimate ``offset_s`` (t_camera = t_stage + offset_s) from the signals alone.

    The whisker is quasi-static, so phi and dz are functions of the stage
    position alone. For a trial offset, every frame gets the stage position at
    its time; the pause means give the signal at each pause position, linear
    interpolation in x predicts every other frame (the ramps of the steps
    included), and the score is the share of the variance of phi (and dz, the
    two averaged) that this explains. A wrong offset puts steps where the
    signal is still and vice versa. Pause lengths differ from step to step,
    which makes the maximum unique. Coarse grid, then a fine grid around the best.

    Returns
    -------
    offset_s : float
        NaN if no offset in the range brings signal frames into the pauses.
    score : float
        The explained share at the estimate, in [0, 1]; near 0 means no contact
        motion was seen and the offset is not determined.
    """
    pauses = detect_pauses(log)
    t = np.asarray(t_camera_s, float)
    # Frames in time order: a pause's frames are then a range of them at every offset.
    order = np.argsort(t, kind="stable")
    t = t[order]
    signals = [np.asarray(phi_deg, float)[order]]
    if dz_mm is not None:
        signals.append(np.asarray(dz_mm, float)[order])
    if pauses.t_start_s.size < 2:
        return math.nan, 0.0
    return best_offset(lambda offsets: _offset_scores(log, pauses, t, signals, offsets), search_s)


def best_offset(score, search_s: tuple[float, float]) -> tuple[float, float]:
    """The clock offset (s) in ``search_s`` that maximises ``score``, and its score.

    ``score(offsets)`` scores a 1-D array of trial offsets (s) at once: an array of the
    same size. Coarse grid, then a fine grid around the best few coarse local maxima:
    with the coarse grid up to half a step off the truth, the true peak can score below
    a wrong offset that shifts the pauses by whole steps (where phi(x) is a plain ramp).
    Near the truth the score is flat up to noise: the middle of the offsets within
    OFFSET_PLATEAU of the best is the estimate.
    """
    lo, hi = search_s
    coarse = np.arange(lo, hi + OFFSET_COARSE_STEP_S / 2, OFFSET_COARSE_STEP_S)
    scores = np.asarray(score(coarse), float)
    interior = np.r_[True, scores[1:] >= scores[:-1]] & np.r_[scores[:-1] >= scores[1:], True]
    peaks = np.flatnonzero(interior)
    peaks = peaks[np.argsort(scores[peaks])[::-1][:OFFSET_CANDIDATES]]
    fines = [np.arange(b - 2 * OFFSET_COARSE_STEP_S, b + 2 * OFFSET_COARSE_STEP_S,
                       OFFSET_FINE_STEP_S) for b in coarse[peaks]]
    # All candidates' fine grids in one call; the first best one wins, as one by one.
    fine_scores = np.split(np.asarray(score(np.concatenate(fines)), float),
                           np.cumsum([f.size for f in fines])[:-1])
    best_fine, best_scores = None, None
    for fine, fs in zip(fines, fine_scores, strict=True):
        if best_scores is None or fs.max() > best_scores.max():
            best_fine, best_scores = fine, fs
    top = best_fine[best_scores >= best_scores.max() - OFFSET_PLATEAU]
    return float(0.5 * (top.min() + top.max())), float(best_scores.max())


@dataclass(frozen=True)
class PauseTable:
    """Per-pause medians (arrays shape (P,)); times on the camera clock."""

    t_start_s: np.ndarray
    t_end_s: np.ndarray
    x_mm: np.ndarray
    phi_deg: np.ndarray
    dz_mm: np.ndarray
    r_mm: np.ndarray
    n_frames: np.ndarray


def pause_medians(log: StageLog, t_camera_s, phi_deg, dz_mm, ok, offset_s: float,
                  pauses: Pauses | None = None) -> PauseTable:
    """Median phi and dz of the trusted frames in each stage pause (the paper's data points).

    Pauses with fewer than :data:`MIN_PAUSE_FRAMES` trusted frames get NaN.
    ``r_mm`` is the median of the log's r_mm over the pause (NaN without it).
    """
    pauses = pauses or detect_pauses(log)
    t = np.asarray(t_camera_s, float)
    phi = np.asarray(phi_deg, float)
    dz = np.asarray(dz_mm, float)
    good = np.asarray(ok).astype(bool) & np.isfinite(phi) & np.isfinite(dz)
    p = pauses.t_start_s.size
    phi_med, dz_med = np.full(p, np.nan), np.full(p, np.nan)
    n = np.zeros(p, int)
    for k, frames in enumerate(pause_frames(t, good, pauses, offset_s)):
        n[k] = frames.size
        if frames.size >= MIN_PAUSE_FRAMES:
            phi_med[k] = np.median(phi[frames])
            dz_med[k] = np.median(dz[frames])
    r_med = log_pause_medians(log, log.r_mm, pauses)
    return PauseTable(
        t_start_s=pauses.t_start_s + offset_s, t_end_s=pauses.t_end_s + offset_s,
        x_mm=pauses.x_mm, phi_deg=phi_med, dz_mm=dz_med, r_mm=r_med, n_frames=n,
    )


# Contact onset: pauses with phi above this are in contact (about 20 times the
# noise of a pause median, 0.22 deg * 1.25 / sqrt(30 frames) ~ 0.05 deg).
CONTACT_PHI_DEG = 1.0
# The onset line is fitted through the contact pauses while phi is still
# linear in travel: below 5 deg the small-deflection beam is within 0.02 deg of
# the elastica (mechanics.whisker.PHI_LINEAR_MAX_DEG).
ONSET_PHI_MAX_DEG = 5.0
# ... or through the first few contact pauses when fewer than two are that small.
ONSET_FIT_PAUSES = 3
# ... and only while phi still rises: a contact that starts to slip under 5 deg levels
# phi off, and a line through that level puts x0 far too early. Two lines (rise, then
# level) replace the one where they fit better by an F statistic over this (by chance
# at p = 0.01 for 10 samples, 0.002 for 20) and the second rises at under this share of
# the first's slope. A rise needs 3 samples to be fitted (2 always fit a line).
ONSET_SPLIT_F = 10.0
ONSET_LEVEL_RATIO = 0.5
ONSET_RISE_MIN = 3


def _line_rss(n, sx, sy, sxx, sxy, syy):
    """Residual sum of squares and slope of the least-squares line, from its sums."""
    vx = sxx - sx * sx / n
    cxy = sxy - sx * sy / n
    slope = np.divide(cxy, vx, out=np.zeros_like(cxy), where=vx > 0)
    return np.maximum(syy - sy * sy / n - slope * cxy, 0.0), slope


def _level_start(u, phi) -> int | None:
    """Where phi (ordered by travel u) levels off: the number of samples in its rise, or
    None where one line fits as well as a rise and a level (:data:`ONSET_SPLIT_F`)."""
    n = u.size
    if n < 5:  # two lines and a residual
        return None
    sums = np.cumsum(np.stack([np.ones(n), u, phi, u * u, u * phi, phi * phi]), axis=1)
    k = np.arange(2, n - 1)  # samples in the rise; the level keeps two or more
    left, total = sums[:, k - 1], sums[:, -1:]
    # The rise's, the level's and the one line's sums side by side: one pass of elementwise
    # arithmetic (the same values as three) for a tenth of a live frame's onset.
    rss, slope = _line_rss(*np.concatenate([left, total - left, total], axis=1))
    m = k.size
    rss_l, slope_l, rss_r, slope_r, rss_1 = rss[:m], slope[:m], rss[m:-1], slope[m:-1], rss[-1:]
    i = int(np.argmin(rss_l + rss_r))
    two = rss_l[i] + rss_r[i]
    f = (rss_1[0] - two) / 2.0 / (two / (n - 4)) if two > 0 else np.inf
    levels = slope_l[i] > 0 and slope_r[i] < ONSET_LEVEL_RATIO * slope_l[i]
    return int(k[i]) if f > ONSET_SPLIT_F and levels else None


def contact_onset_x(x_mm, phi_deg, travel_sign: float = 1.0):
    """Stage position of first contact, from pause medians or from frames of a continuous sweep.

    Fits phi = a (x - x0) through the pauses with :data:`CONTACT_PHI_DEG` <= phi <
    :data:`ONSET_PHI_MAX_DEG` before phi first leaves that range, up to where phi
    levels off (:func:`_level_start`), or through the first
    :data:`ONSET_FIT_PAUSES` contact pauses if fewer than two, and returns x0
    (where phi extrapolates to zero); a rise of fewer than :data:`ONSET_RISE_MIN`
    pauses before the level gives the line through the first contact pause and the
    pause before it. A single contact pause gives the midpoint between it and the
    pause before. NaN if phi never reaches the threshold.
    """
    x = np.asarray(x_mm, float)
    phi = np.asarray(phi_deg, float)
    order = np.argsort(travel_sign * x, kind="stable")
    x, phi = x[order], phi[order]
    finite = np.isfinite(phi) & np.isfinite(x)
    x, phi = x[finite], phi[finite]
    hit = np.flatnonzero(phi >= CONTACT_PHI_DEG)
    if hit.size == 0:
        return math.nan
    first = hit[0]
    linear = phi[first:] < ONSET_PHI_MAX_DEG
    n_linear = int(np.argmin(linear)) if not linear.all() else linear.size
    use = np.arange(first, first + n_linear)
    # Not the samples after contact is lost (a whisker that slides off under 5 deg).
    touching = np.flatnonzero(phi[use] >= CONTACT_PHI_DEG)
    use = use[:touching[-1] + 1] if touching.size else use
    rise = _level_start(travel_sign * x[use], phi[use])
    if rise is not None and rise < ONSET_RISE_MIN:
        # The second sample may be on the level already: the first and the one before it
        # (at rest, or in contact under CONTACT_PHI_DEG) bracket the onset.
        use = np.arange(max(first - 1, 0), first + 1)
    elif rise is not None:
        use = use[:rise]
    elif use.size < 2:
        use = hit[:ONSET_FIT_PAUSES]
    xu = x[use]
    if use.size < 2 or xu.max() == xu.min():  # frames at one position carry no slope
        return float(x[first] - 0.5 * travel_sign * abs(x[first] - x[max(first - 1, 0)]))
    slope, intercept = np.polyfit(xu, phi[use], 1)
    if slope * travel_sign <= 0:
        return float(x[first])
    x0 = -intercept / slope
    # The onset lies between the log's first pause and the first contact pause (clipped in
    # Python: np.clip's wrapper costs more than the rest of a live frame's onset).
    a, b = sorted((float(x[0]), float(x[first])))
    return min(max(float(x0), a), b)
