"""The Pareto front of speed (higher is better) against errors (lower is better)."""

from __future__ import annotations

import numpy as np

__all__ = ["pareto_front"]


def pareto_front(speed: np.ndarray, error: np.ndarray, speed_tol: float = 0.0,
                 error_tol: float = 0.0) -> np.ndarray:  # fmt: skip
    """Which points no other point dominates, shape (N,) bool.

    A point dominates another when it is at least as fast and at least as
    accurate on every error axis, and strictly better in one of them. Speeds
    within a relative ``speed_tol`` of each other count as equal (a timing's
    own spread), so a point dominates by speed alone only when it is faster by
    more than that; errors within a relative ``error_tol`` count as equal
    likewise. Points with a NaN are never on the front (and dominate nothing).

    Parameters
    ----------
    speed : ndarray, shape (N,)
        frames/s.
    error : ndarray, shape (N,) or (N, K)
        Error, any unit; K error axes (e.g. phi and dz RMSE), each lower-is-better.
    speed_tol : float
        Relative spread of the speeds (0.05: 5 %).
    error_tol : float
        Relative difference of errors below which they are not told apart.
    """
    s = np.asarray(speed, float)
    e = np.asarray(error, float).reshape(len(s), -1)
    valid = np.isfinite(s) & np.isfinite(e).all(axis=1)
    front = valid.copy()
    for i in np.flatnonzero(valid):
        not_slower = s >= s[i] * (1.0 - speed_tol)
        faster = s > s[i] * (1.0 + speed_tol)
        not_worse = (e <= e[i] * (1.0 + error_tol)).all(axis=1)
        better = (e < e[i] * (1.0 - error_tol)).any(axis=1)
        others = valid & not_slower & not_worse & (faster | better)
        others[i] = False
        front[i] = not others.any()
    return front
