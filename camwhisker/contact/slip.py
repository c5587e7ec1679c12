"""Slip from GM's own estimates: a stuck contact keeps its distance, a slipping one runs away.

Eq. (8) assumes the contact point stays where it was touched. While it does,
r_GM stays put as the base travels (it drifts outward only as far as the
contact rolls along the bending whisker, well under :data:`STUCK_RATE` mm per
mm of travel). When the contact slips along a surface, phi stops growing while
the base goes on, and r_GM runs away at several mm per mm. r_GM is summarised
per :data:`TRAVEL_BIN_MM` of travel by its median (frame by frame, the frames
of a stage pause share a bin, and the few of the moves between, whose local
line straddles a start or a stop, cannot outvote them). A bin slips where its
r_GM has risen since the bin :data:`BASELINE_MM` of travel before by more than
a stuck contact's drift plus :data:`NOISE_SIGMAS` of the pair's GM spread, and
is stuck where it has risen by less than that drift; in between, the state is
the one before (a slide near the noise does not flicker).

Stick and slip are then separate segments of the fusion (:func:`slip_segments`):
the bias a slide gives GM is not averaged back into the stuck samples before it,
where GM is right.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from camwhisker.contact.fusion import segment_start

__all__ = ["STUCK_RATE", "BASELINE_MM", "TRAVEL_BIN_MM", "NOISE_SIGMAS", "slipping", "slip_state",
           "slip_segments", "slipped", "OnlineSlip"]

# Largest outward drift of a stuck contact's r_GM per mm of travel: the contact rolls
# along the bending whisker by 0.1-0.5 mm per mm on the calibration's pegs; a contact
# slipping up a wall gives an r_GM that runs out at 2.7-9.5 mm per mm (tuning sweeps 0,
# 3, 6, 13, 53; the contact bench's box: 4).
STUCK_RATE = 1.0
# Travel over which the rise is measured: one stage step, the pauses' spacing.
BASELINE_MM = 1.0
# r_GM is compared bin by bin of travel (the median of each): a quarter of a stage step.
TRAVEL_BIN_MM = 0.25
# Rises within this many of the pair's GM spreads are noise.
NOISE_SIGMAS = 3.0
# Live: the bins kept (a baseline back is 4 bins), and the samples whose median a bin
# takes (a pause of 2 s at 30 frames/s; the median of a longer pause hardly moves).
ONLINE_BINS = 8
ONLINE_BIN_SAMPLES = 64


def slipping(r_gm_mm, dx_mm, sigma_gm_mm, segment=None) -> np.ndarray:
    """Per sample (time order within a segment): has r_GM run away since BASELINE_MM before?

    Parameters
    ----------
    r_gm_mm, dx_mm, sigma_gm_mm : array_like, shape (N,)
        GM's estimate, the travel since the contact's onset and GM's spread.
    segment : array_like of int, shape (N,), optional
        Contact id per sample; no comparison crosses a change.

    Returns
    -------
    ndarray, shape (N,)
        1.0 slipping, 0.0 stuck, NaN where undecided (between the two thresholds), where any
        input is undefined or where no sample lies a baseline back.
    """
    r = np.asarray(r_gm_mm, float)
    dx = np.asarray(dx_mm, float)
    sg = np.asarray(sigma_gm_mm, float)
    seg = np.zeros(r.shape, int) if segment is None else np.asarray(segment)
    out = np.full(r.shape, np.nan)
    good = np.isfinite(r) & np.isfinite(dx) & np.isfinite(sg)
    for s in np.unique(seg):
        idx = np.flatnonzero((seg == s) & good)
        if idx.size < 2:
            continue
        # The travel only grows within a contact. Per bin of travel, the median r_GM: a
        # pause's frames share one bin, and a few frames of the moves between do not move it.
        travel = np.maximum.accumulate(dx[idx])
        _, first, which = np.unique(np.floor(travel / TRAVEL_BIN_MM), return_index=True,
                                    return_inverse=True)
        parts = np.split(np.arange(idx.size), first[1:])
        rb = np.array([np.median(r[idx[p]]) for p in parts])
        tb = np.array([travel[p[-1]] for p in parts])
        sb = np.array([np.max(sg[idx[p]]) for p in parts])
        # The latest bin a baseline back.
        j = np.searchsorted(tb, tb - BASELINE_MM, side="right") - 1
        has = j >= 0
        i, b = np.flatnonzero(has), j[has]
        rise = rb[i] - rb[b]
        drift = STUCK_RATE * (tb[i] - tb[b])
        slip = rise > drift + NOISE_SIGMAS * np.hypot(sb[i], sb[b])
        state = np.full(rb.size, np.nan)
        state[i] = np.where(slip, 1.0, np.where(rise < drift, 0.0, np.nan))
        out[idx] = state[which]
    return out


def slip_state(slip, segment=None) -> np.ndarray:
    """Per sample 1.0 (slipping) or 0.0: an undefined state keeps the one before it in its
    segment, and is stuck at the segment's start."""
    slip = np.asarray(slip, float)
    seg = np.zeros(slip.shape, int) if segment is None else np.asarray(segment)
    new = np.r_[True, np.diff(seg) != 0]
    state = np.where(np.isnan(slip) & new, 0.0, slip)
    last = np.where(~np.isnan(state), np.arange(state.size), 0)
    return state[np.maximum.accumulate(last)]


def slip_segments(state, segment=None) -> np.ndarray:
    """Segment ids (from 0) that also change wherever the :func:`slip_state` ``state`` does."""
    seg = np.zeros(np.shape(state), int) if segment is None else np.asarray(segment)
    if seg.size == 0:
        return np.zeros(0, int)
    change = np.r_[True, (np.diff(seg) != 0) | (np.diff(np.asarray(state, float)) != 0)]
    return np.cumsum(change) - 1


def slipped(state, segment=None) -> np.ndarray:
    """Per sample, has its contact slipped at or before it (:func:`slip_state` ``state`` > 0)?

    Eq. (8) takes the travel since the contact's onset: once the contact has slid, GM's r is
    off for the rest of the contact, stuck again or not.
    """
    on = np.asarray(state, float) > 0
    seg = np.zeros(on.shape, int) if segment is None else np.asarray(segment)
    if on.size == 0:
        return on
    start = segment_start(seg)
    count = np.cumsum(on)
    before = np.where(start > 0, count[np.maximum(start - 1, 0)], 0)
    return count - before > 0


class OnlineSlip:
    """:func:`slip_state` of :func:`slipping` one sample at a time, for live use.

    The same bins and thresholds over one contact's samples so far: the newest bin's
    median is over its samples up to now (its newest :data:`ONLINE_BIN_SAMPLES`).
    """

    def __init__(self):
        self._bins: deque = deque(maxlen=ONLINE_BINS)
        self._travel = -math.inf
        self.state = 0.0
        self.slipped = False  # :func:`slipped` for the newest sample

    def __call__(self, r_gm_mm: float, dx_mm: float, sigma_gm_mm: float) -> float:
        """The slip state (1.0 or 0.0) after one sample; an undefined one keeps it."""
        if not (math.isfinite(r_gm_mm) and math.isfinite(dx_mm) and math.isfinite(sigma_gm_mm)):
            return self.state
        self._travel = max(self._travel, dx_mm)
        b = math.floor(self._travel / TRAVEL_BIN_MM)
        if not self._bins or self._bins[-1][0] != b:
            self._bins.append([b, self._travel, deque(maxlen=ONLINE_BIN_SAMPLES), sigma_gm_mm])
        cur = self._bins[-1]
        cur[1] = self._travel
        cur[2].append(r_gm_mm)
        cur[3] = max(cur[3], sigma_gm_mm)
        base = next((q for q in reversed(self._bins) if q[1] <= self._travel - BASELINE_MM),
                    None)
        if base is None:
            return self.state
        rise = _median(cur[2]) - _median(base[2])
        drift = STUCK_RATE * (cur[1] - base[1])
        if rise > drift + NOISE_SIGMAS * math.hypot(cur[3], base[3]):
            self.state = 1.0
            self.slipped = True
        elif rise < drift:
            self.state = 0.0
        return self.state


def _median(values) -> float:
    """np.median of finite values (the same bits: the middle one, or the two middle ones'
    sum halved) by a sort in Python, which for a bin's few samples costs a tenth."""
    v = sorted(values)
    m = len(v) // 2
    return v[m] if len(v) % 2 else (v[m - 1] + v[m]) / 2.0
