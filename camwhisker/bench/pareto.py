"""The Pareto front of speed (higher is better) against error (lower is better)."""

from __future__ import annotations

import numpy as np

__all__ = ["pareto_front"]


def pareto_front(speed: np.ndarray, error: np.ndarray) -> np.ndarray:
    """Which points no other point dominates, shape (N,) bool.

    A point dominates another when it is at least as fast and at least as
    accurate, and strictly better in one of the two. Points with a NaN are
    never on the front (and dominate nothing).

    Parameters
    ----------
    speed : ndarray, shape (N,)
        frames/s.
    error : ndarray, shape (N,)
        Error, any unit.
    """
    s = np.asarray(speed, float)
    e = np.asarray(error, float)
    valid = np.isfinite(s) & np.isfinite(e)
    front = valid.copy()
    for i in np.flatnonzero(valid):
        others = valid & (s >= s[i]) & (e <= e[i]) & ((s > s[i]) | (e < e[i]))
        front[i] = not others.any()
    return front
