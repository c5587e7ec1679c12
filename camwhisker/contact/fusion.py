"""Fusing the GM and MF estimates over a contact.

GM is precise but fails on compliant or slipping contact, and then its error
is a slowly changing bias; MF is noisy but unbiased. Within one contact
(samples in time order), a two-sided exponentially weighted mean m of the
difference d = r_GM - r_MF (weights 1 / (sigma_GM^2 + sigma_MF^2), with
sigma_MF MF's scatter from noise, the calibration's ``mf_noise``; memory
:data:`MEMORY_SAMPLES` on each side) estimates the GM bias with standard error
se. Two-sided, because the early samples of a contact (small phi) have no MF
(below the table's phi floor) and borrow the later ones; the contact command
works on whole recordings, so looking ahead is allowed. se is floored by the
per-contact systematic error of MF (``floor_mm``), because MF's errors are not
independent from sample to sample.

GM is "good" (m ~ N(0, se^2)) with prior :data:`PRIOR_GM_GOOD`, or failed
(m spread over the whisker, density 1 / l_w). With p the posterior of "good",
the fused estimate is

    r_fused = r_GM - (1 - p) m   where p < KEEP_GM_POSTERIOR, else r_GM,

GM itself where the evidence says it is fine, and GM with its bias removed by
the MF evidence where it is not. (Where p >= :data:`KEEP_GM_POSTERIOR` the
posterior-mean correction is under a tenth of m, and m is then mostly MF's own
per-contact error, so applying it would move a good GM toward MF's bias.)
Where MF is undefined, GM is returned; where GM is undefined, MF.

A slipping contact (:mod:`~camwhisker.contact.slip`) is its own segment: GM's
fixed contact is broken there by construction and its bias grows along the
slide, so m is the value of a weighted two-sided line through d (not its mean,
which lags the growth by the memory at both ends of the slide) and is taken
off whole: r_fused = r_GM - m.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter

from camwhisker.contact.mf import SAME_RADIUS_MM

__all__ = ["PRIOR_GM_GOOD", "MEMORY_SAMPLES", "MF_BIAS_FLOOR_MM", "KEEP_GM_POSTERIOR",
           "mf_bias_floor_mm", "segment_start", "fuse", "gm_error_score", "OnlineFusion"]

# Prior share of good GM estimates: rigid, non-slipping contact is the common case,
# and a 3 % prior of failure lets a consistent bias of a few sigma overturn it.
PRIOR_GM_GOOD = 0.97
# Memory of the bias estimate on each side (samples = stage pauses): averages MF's
# noise over ~10 pauses yet follows a GM bias that changes by up to 1 mm a step.
MEMORY_SAMPLES = 5.0
# Floor on the standard error of the bias estimate: MF's systematic error over one
# contact (it interpolates between calibrated radii), which averaging does not remove,
# for calibration pegs spaced as the paper's; other spacings: mf_bias_floor_mm.
MF_BIAS_FLOOR_MM = 2.0
# The paper's pegs' widest gap between neighbouring radii, relative to their geometric
# mean: 33.5 -> 42.5 mm.
PAPER_PEG_GAP = 9.0 / math.sqrt(33.5 * 42.5)
# Posterior P(GM good) at or above which GM is returned unchanged: the correction
# (1 - p) m would be under 0.1 m, i.e. under 0.2 mm for an m at the 2 mm floor
# (GM's own spread, sigma_GM, is 0.3-1 mm), so it cannot be told from MF's bias.
KEEP_GM_POSTERIOR = 0.9


def mf_bias_floor_mm(radii_mm) -> float:
    """The floor for MF calibrated on runs at ``radii_mm``: :data:`MF_BIAS_FLOOR_MM` scaled
    by the widest gap between neighbouring radii (relative to their geometric mean) against
    the paper's pegs'. MF answers near its calibrated curves, so its error over a contact
    between two of them grows with their spacing (worst 3.1 mm on the paper's 8 pegs,
    1.8 mm on 15 evenly in log r: tests/test_contact_mf.py). Radii within
    :data:`~camwhisker.contact.mf.SAME_RADIUS_MM` of the one before are one."""
    r = np.sort(np.asarray(radii_mm, float).ravel())
    r = r[np.isfinite(r) & (r > 0)]
    r = r[np.r_[True, np.diff(r) >= SAME_RADIUS_MM]] if r.size else r
    if r.size < 2:
        raise ValueError("MF's floor needs runs at two or more radii")
    gap = float(np.max(np.diff(r) / np.sqrt(r[:-1] * r[1:])))
    return MF_BIAS_FLOOR_MM * gap / PAPER_PEG_GAP


def segment_start(segment) -> np.ndarray:
    """Per sample, the index of the first sample of its segment (a run of equal ids)."""
    idx = np.arange(np.size(segment))
    return np.maximum.accumulate(np.where(np.r_[True, np.diff(segment) != 0], idx, 0))


def _two_sided(v, segment, memory):
    """Two-sided exponentially weighted sums of v within each segment.

    Forward and backward first-order recursions (lambda = 1 - 1/memory) over the
    whole array, each segment's share of the one before it taken off (a sample i
    places after a segment starting at s carries lambda^(i - s + 1) of the sum at
    s - 1); the sample itself is counted once.
    """
    lam = 1.0 - 1.0 / memory
    idx = np.arange(v.size)

    def forward(x, seg):
        f = lfilter([1.0], [1.0, -lam], x)
        start = segment_start(seg)
        before = np.where(start > 0, f[np.maximum(start - 1, 0)], 0.0)
        return f - lam ** (idx - start + 1.0) * before

    return forward(v, segment) + forward(v[::-1], segment[::-1])[::-1] - v


def _bias(d, w, segment, memory, trend):
    """The GM bias m and its variance at each sample: the weighted two-sided mean of d,
    or where ``trend``, the value at the sample of a weighted two-sided line through d."""
    sums = {"w": _two_sided(w, segment, memory), "wd": _two_sided(w * d, segment, memory)}
    seen = sums["w"] > 0
    m = np.divide(sums["wd"], sums["w"], out=np.full(d.shape, np.nan), where=seen)
    var = np.divide(1.0, sums["w"], out=np.ones(d.shape), where=seen)
    if trend is None or not np.any(trend):
        return m, var, seen
    # Sample index from the segment's start: small numbers, no cancellation in k^2.
    k = (np.arange(d.size) - segment_start(segment)).astype(float)
    wk = _two_sided(w * k, segment, memory)
    s1 = wk - k * sums["w"]
    s2 = _two_sided(w * k * k, segment, memory) - 2 * k * wk + k * k * sums["w"]
    t1 = _two_sided(w * d * k, segment, memory) - k * sums["wd"]
    det = sums["w"] * s2 - s1 * s1
    # A line needs two samples of weight: det > 0 by more than rounding.
    line = np.asarray(trend, bool) & (det > 1e-9 * np.maximum(sums["w"] * s2, 1e-300))
    m = np.where(line, np.divide(sums["wd"] * s2 - t1 * s1, det, out=m.copy(), where=line), m)
    # Never below the mean's variance (rounding in s2 could take it there).
    var = np.where(line, np.maximum(np.divide(s2, det, out=var.copy(), where=line), var), var)
    return m, var, seen


def fuse(r_gm_mm, r_mf_mm, sigma_gm_mm, sigma_mf_mm, l_w_mm, segment=None, trend=None,
         prior_good=PRIOR_GM_GOOD, memory=MEMORY_SAMPLES, floor_mm=MF_BIAS_FLOOR_MM,
         keep_gm=KEEP_GM_POSTERIOR):
    """Fuse GM and MF (module docstring); samples of a segment must be in time order.

    Parameters
    ----------
    r_gm_mm, r_mf_mm, sigma_gm_mm, sigma_mf_mm : array_like, shape (N,)
    l_w_mm : float
    segment : array_like of int, shape (N,), optional
        Contact (run) id per sample; the bias estimate does not cross a change.
        Default: one segment.
    trend : array_like of bool, shape (N,), optional
        Samples whose segment has a GM bias that grows along it (a slipping contact:
        :mod:`~camwhisker.contact.slip`): m there is a local line's value, not a mean.
    floor_mm : float
        Per-contact systematic error of MF allowed for a good GM.
    keep_gm : float
        Posterior P(GM good) at or above which GM is returned unchanged.

    Returns
    -------
    r_mm, p_good, bias_mm : ndarray, shape (N,)
        Fused estimate; posterior that GM is good and the GM bias estimate
        (both NaN in a segment without a sample where GM and MF are defined).
    """
    r_gm, r_mf, w, d = _weights(r_gm_mm, r_mf_mm, sigma_gm_mm, sigma_mf_mm)
    seg = np.zeros(r_gm.shape, int) if segment is None else np.asarray(segment)
    m, var, seen = _bias(d, w, seg, memory, trend)
    return _posterior(m, var, seen, r_gm, r_mf, l_w_mm, prior_good, floor_mm, keep_gm, trend)


def _weights(r_gm_mm, r_mf_mm, sigma_gm_mm, sigma_mf_mm):
    """r_GM, r_MF as arrays, and each sample's weight 1 / (sigma_GM^2 + sigma_MF^2) and
    difference d = r_GM - r_MF (both 0 where either estimate or spread is undefined)."""
    r_gm = np.atleast_1d(np.asarray(r_gm_mm, float))
    r_mf = np.atleast_1d(np.asarray(r_mf_mm, float))
    s_gm = _shaped(sigma_gm_mm, r_gm.shape)
    s_mf = _shaped(sigma_mf_mm, r_gm.shape)
    both = (np.isfinite(r_gm) & np.isfinite(r_mf) & np.isfinite(s_gm) & np.isfinite(s_mf)
            & (s_gm > 0) & (s_mf > 0))
    var = np.where(both, s_gm**2 + s_mf**2, 1.0)
    return r_gm, r_mf, np.where(both, 1.0 / var, 0.0), np.where(both, r_gm - r_mf, 0.0)


def _shaped(v, shape):
    """v as a float array of ``shape``; np.broadcast_to only where it is not already (the
    live loop's one sample: its Python wrapper costs more than the sample's arithmetic)."""
    v = np.asarray(v, float)
    return v if v.shape == shape else np.broadcast_to(v, shape)


def _zero_nan(v):
    """v with NaN as 0: np.nan_to_num's checks for infinities (neither a bias nor a
    probability is one) are slow in the live loop."""
    return np.where(np.isnan(v), 0.0, v)


def _posterior(m, var, seen, r_gm, r_mf, l_w_mm, prior_good, floor_mm, keep_gm, trend=None):
    """P(GM good) and the fused estimate from the bias estimate m (module docstring);
    ``var``: m's variance (a weighted mean's, weights w_i = 1 / variance_i: 1 / sum(w)).
    Where ``trend`` (a slip), GM is known to be broken: m is taken off whole."""
    se2 = var + floor_mm**2
    m0 = _zero_nan(m)
    like_good = prior_good * np.exp(-0.5 * m0**2 / se2) / np.sqrt(2.0 * np.pi * se2)
    like_bad = (1.0 - prior_good) / l_w_mm
    gm_ok = np.isfinite(r_gm)
    p_good = np.where(seen & gm_ok, like_good / (like_good + like_bad), np.nan)
    p0 = _zero_nan(p_good)
    shift = np.where(p0 >= keep_gm, 0.0, (1.0 - p0) * m0)
    if trend is not None:
        shift = np.where(trend, m0, shift)
    fused = np.where(seen & gm_ok, r_gm - shift, np.nan)
    fused = np.where(~seen & gm_ok, r_gm, fused)
    fused = np.where(~gm_ok & np.isfinite(r_mf), r_mf, fused)
    return fused, p_good, m


def gm_error_score(gm_bias_mm, error_mm, floor_mm: float = MF_BIAS_FLOOR_MM) -> np.ndarray:
    """The flag "GM may be off by more than ``error_mm``" as a score, flagged where > 0.

    The fusion's estimate m of GM's bias (``gm_bias_mm``) is known to MF's per-contact
    systematic error ``floor_mm`` at best, so GM may be off by ``error_mm`` where
    |m| > error_mm - floor_mm: the score is |m| - (error_mm - floor_mm), NaN where m is.
    ``error_mm``: a scalar (the paper's 15 mm) or per sample (3 sigma_GM).
    """
    m = np.abs(np.asarray(gm_bias_mm, float))
    return m - (np.asarray(error_mm, float) - floor_mm)


class OnlineFusion:
    """:func:`fuse` one sample at a time, for live use: the forward recursion alone.

    The two-sided sums of :func:`fuse` at the newest sample of a segment are its
    forward sums (no later sample to add), so each call returns what :func:`fuse`
    gives for the newest sample of all the samples so far (one segment). A change
    of ``trend`` (a slip starting or ending) starts a new segment, as in :func:`fuse`;
    in a slip the line's sums are carried too, with offsets from the newest sample.
    """

    def __init__(self, prior_good=PRIOR_GM_GOOD, memory=MEMORY_SAMPLES,
                 floor_mm=MF_BIAS_FLOOR_MM, keep_gm=KEEP_GM_POSTERIOR):
        self._lam = 1.0 - 1.0 / memory
        self._args = (prior_good, floor_mm, keep_gm)
        self._trend = False
        # Python floats: the same IEEE arithmetic as numpy's scalars, without their overhead.
        self._sums = (0.0,) * 5  # sum of w, w d, w k, w k^2, w d k (k: offset, <= 0)

    def __call__(self, r_gm_mm, r_mf_mm, sigma_gm_mm, sigma_mf_mm, l_w_mm, trend=False):
        """(r_mm, p_good, bias_mm), arrays shape (1,), for one sample (as :func:`fuse`)."""
        r_gm, r_mf, s_gm, s_mf = (np.asarray(v, float).item()
                                  for v in (r_gm_mm, r_mf_mm, sigma_gm_mm, sigma_mf_mm))
        w0 = d0 = 0.0  # as _weights: both estimates and spreads defined, else no weight
        if (math.isfinite(r_gm) and math.isfinite(r_mf) and math.isfinite(s_gm)
                and math.isfinite(s_mf) and s_gm > 0 and s_mf > 0):  # fmt: skip
            w0, d0 = 1.0 / (s_gm * s_gm + s_mf * s_mf), r_gm - r_mf
        if bool(trend) != self._trend:
            self._trend = bool(trend)
            self._sums = (0.0,) * 5
        s0, s_d, s1, s2, t1 = self._sums
        lam = self._lam
        # Every earlier sample's offset from the newest grows by one: k -> k - 1.
        self._sums = s0, s_d, s1, s2, t1 = (lam * s0 + w0, lam * s_d + w0 * d0, lam * (s1 - s0),
                                             lam * (s2 - 2.0 * s1 + s0), lam * (t1 - s_d))
        m, var = (s_d / s0, 1.0 / s0) if s0 > 0 else (math.nan, 1.0)
        det = s0 * s2 - s1 * s1
        if self._trend and det > 1e-9 * max(s0 * s2, 1e-300):
            m, var = (s_d * s2 - t1 * s1) / det, max(s2 / det, var)
        return tuple(np.array([v]) for v in _posterior_one(
            m, var, s0 > 0, r_gm, r_mf, l_w_mm, *self._args, self._trend))


def _posterior_one(m, var, seen, r_gm, r_mf, l_w_mm, prior_good, floor_mm, keep_gm, trend):
    """:func:`_posterior` of one sample in Python floats: the same operations in the same
    order (exp by numpy, x**2 of an array as x * x), so the same bits."""
    se2 = var + floor_mm**2
    m0 = 0.0 if math.isnan(m) else m
    like_good = prior_good * float(np.exp(-0.5 * (m0 * m0) / se2)) / math.sqrt(
        2.0 * math.pi * se2)
    like_bad = (1.0 - prior_good) / l_w_mm
    gm_ok = math.isfinite(r_gm)
    p_good = like_good / (like_good + like_bad) if seen and gm_ok else math.nan
    p0 = 0.0 if math.isnan(p_good) else p_good
    shift = m0 if trend else (0.0 if p0 >= keep_gm else (1.0 - p0) * m0)
    if gm_ok:
        fused = r_gm - shift if seen else r_gm
    else:
        fused = r_mf if math.isfinite(r_mf) else math.nan
    return fused, p_good, m
