"""Per-frame signals smoothed by a local line in time, for the per-frame contact estimates.

A frame's phi and dz carry the front end's noise (the paper's: 0.22 deg,
0.04 mm), which the paper averages away with the median over a stage pause.
While the base moves there is no pause; quasi-statically phi(t) follows x(t),
which is piecewise linear in time, so a line fitted over a short centred
window keeps the trend and averages the noise like a pause of that length.
"""

from __future__ import annotations

import functools
import math

import numpy as np

__all__ = ["local_line", "local_line_newest"]


def local_line(values, half_frames: int) -> np.ndarray:
    """Value at each sample of the least-squares line over samples i-h..i+h (NaNs skipped).

    Parameters
    ----------
    values : array_like, shape (N,)
    half_frames : int
        h; 0 returns the values unchanged.

    Returns
    -------
    ndarray, shape (N,)
        NaN where the sample itself is NaN or its window holds fewer than 3 finite samples.
    """
    y = np.asarray(values, float)
    if half_frames <= 0 or y.size == 0:
        return y.copy()
    good = np.isfinite(y)
    g = good.astype(float)
    yz = np.where(good, y, 0.0)
    tau = np.arange(-half_frames, half_frames + 1, dtype=float)
    # Correlating with the kernels: sums over the window of 1, tau, tau^2, y, tau y.
    s0 = np.correlate(g, np.ones_like(tau), "same")
    s1 = np.correlate(g, tau, "same")
    s2 = np.correlate(g, tau * tau, "same")
    sy = np.correlate(yz, np.ones_like(tau), "same")
    sty = np.correlate(yz, tau, "same")
    det = s0 * s2 - s1 * s1
    with np.errstate(invalid="ignore", divide="ignore"):
        fit = _line_value(s2, s1, sy, sty, det)
    return np.where(good & (s0 >= 3) & (det > 0), fit, np.nan)


def _line_value(s2, s1, sy, sty, det):
    """The least-squares line's value at tau = 0 from its window's sums."""
    return (s2 * sy - s1 * sty) / det


def local_line_newest(values, half_frames: int) -> float:
    """:func:`local_line` at the newest sample with the later ones missing (a live frame),
    from the last h + 1 ``values``: the same sums (the window's dot products with the
    kernels, the missing samples as zeros), so the same bits, without the other samples'."""
    h = half_frames
    y = [float(v) for v in values][-(max(h, 0) + 1):]
    if h <= 0 or not y:  # h 0: the value itself, as local_line
        return y[-1] if y else math.nan
    if not math.isfinite(y[-1]):
        return math.nan
    good = [math.isfinite(v) for v in y]
    seen = [v if ok else 0.0 for v, ok in zip(y, good, strict=True)]
    # The window, tau = -h .. h: the newest at 0, the earlier missing and the later as zeros.
    pad = np.array([0.0] * (h + 1 - len(y)) + seen + [0.0] * h)
    taus = [t for t, ok in zip(range(1 - len(y), 1), good, strict=True) if ok]
    # Sums of small whole numbers: exact in any order.
    s0, s1, s2 = float(len(taus)), float(sum(taus)), float(sum(t * t for t in taus))
    det = s0 * s2 - s1 * s1
    if not (s0 >= 3 and det > 0):
        return math.nan
    ones, tau = _kernels(h)
    return float(_line_value(s2, s1, np.dot(pad, ones), np.dot(pad, tau), det))


@functools.lru_cache(maxsize=8)
def _kernels(h: int) -> tuple[np.ndarray, np.ndarray]:
    """local_line's kernels for h: ones and tau = -h .. h."""
    tau = np.arange(-h, h + 1, dtype=float)
    return np.ones_like(tau), tau
