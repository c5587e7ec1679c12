"""Per-frame signals smoothed by a local line in time, for the per-frame contact estimates.

A frame's phi and dz carry the front end's noise (the paper's: 0.22 deg,
0.04 mm), which the paper averages away with the median over a stage pause.
While the base moves there is no pause; quasi-statically phi(t) follows x(t),
which is piecewise linear in time, so a line fitted over a short centred
window keeps the trend and averages the noise like a pause of that length.
"""

from __future__ import annotations

import numpy as np

__all__ = ["local_line"]


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
        fit = (s2 * sy - s1 * sty) / det  # the line's value at tau = 0
    return np.where(good & (s0 >= 3) & (det > 0), fit, np.nan)
