"""Contact belief and onset from the signals alone (eq. 1 of the seed paper).

The paper's whiskers report a 2D deflection vector d(t); its contact belief is

    b(t) = clip(|d(t)| / eta - 1, 0, 1)                                  (eq. 1)

with eta "the peak value of |d| seen in no-contact trials plus about 50 %".
Here d is the plate's tilt as a 2D vector, (phi cos theta, phi sin theta) in
degrees, relative to rest. Its norm is the signal table's ``phi_deg`` itself:
the table's pose is measured against the rest reference (the mean image of the
rest frames, :mod:`camwhisker.vision.stream`), so the rest offset is already zero, and
theta is not needed (it is left empty below 0.6 deg, far above the rest noise,
so the vector's components cannot be formed there anyway). dz is left out: a
lateral contact, the one a robot whisker meets, moves dz only to second order in
phi (the beam's shortening), so dz leaves its noise long after phi does and would
add only its own false alarms; and mixing mm with degrees would need a scale the
paper does not give.

eta comes from the recording's own rest frames (the rest segment the stream
averaged for its reference, recorded in the sidecar): ``ETA_FACTOR`` times the
``ETA_QUANTILE`` quantile of |d| over them, the paper's "peak plus 50 %" made
robust to one bad frame, and never under ``ETA_FLOOR_DEG``: a whisker back from a
contact settles a little off its rest (the springs' hysteresis), and a short or very
quiet rest would otherwise put eta under that level, so the contact would never end.

Contact (per frame, causal, so live can use it): entered where b reaches 1 and
left where b falls back to 0, a hysteresis over eq. 1's whole band, so noise
around either threshold cannot toggle it. Untrusted rows (NaN) keep the state.

Onset (per contact, looks back): the frame where the contact was entered is
refined back to where the signal left the noise: the rise above eta up to the
detecting frame is fitted with a line (least squares), and the onset is the
first frame after the line's zero. A deflection that grows linearly from contact
(a base moving at constant speed, small deflection) puts that zero within one
frame of the true onset, however slowly it rises. A rise past eta in a single
frame has no line: the onset is that frame, or the one before where that one
already stands above the rest noise's peak (eta / ETA_FACTOR).

References
----------
Pearson, M. J., et al. (seed paper 000), eq. 1: contact belief from whisker deflection.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "ETA_QUANTILE", "ETA_FACTOR", "ETA_FLOOR_DEG", "MIN_REST_FRAMES", "Onset", "contact_belief",
    "eta_from_rest", "eta_source", "next_contact", "contact_flag", "find_onsets",
]  # fmt: skip

#: Quantile of the rest frames' |d| taken as their "peak": over a 1 s rest (30 frames)
#: it is the second-largest value, so one bad frame does not set eta.
ETA_QUANTILE = 0.95
#: The paper's "plus about 50 %" over the no-contact peak.
ETA_FACTOR = 1.5
#: Fewest trusted rest frames whose quantile stands alone (a 1 s rest gives 30); with
#: fewer, eta is their quantile all the same, and the floor below carries it.
MIN_REST_FRAMES = 5
#: Least eta (deg): twice the 0.01 deg off rest at which a hand-made build's whisker
#: settled after a contact, so that it reads as rest, not contact.
ETA_FLOOR_DEG = 0.02


@dataclass(frozen=True)
class Onset:
    """One contact: its refined first frame, the frame where b reached 1, and its last
    frame in contact (the last row of the table where it never ended)."""

    frame: int
    detected_frame: int
    end_frame: int

    def as_dict(self, t_s: np.ndarray | None = None) -> dict:
        out = {"frame": self.frame, "detected_frame": self.detected_frame,
               "end_frame": self.end_frame}  # fmt: skip
        if t_s is not None:
            out["t_s"] = float(t_s[self.frame])
        return out


def contact_belief(d: np.ndarray | float, eta: float) -> np.ndarray | float:
    """Eq. 1: b = clip(|d| / eta - 1, 0, 1), NaN where d is.

    Parameters
    ----------
    d : ndarray, shape (N,) or (N, 2), or float
        The deflection's norm, or the deflection vectors (their norm is taken); a float
        gives a float.
    eta : float
        The no-contact noise level (same unit as d), > 0.
    """
    if not eta > 0 or not math.isfinite(eta):
        raise ValueError(f"eta must be positive and finite, got {eta}")
    if isinstance(d, float):  # one live frame: the same operations in Python floats
        return min(max(abs(d) / eta - 1.0, 0.0), 1.0)
    d = np.asarray(d, float)
    norm = np.hypot(d[:, 0], d[:, 1]) if d.ndim == 2 else np.abs(d)
    v = norm / eta - 1.0  # Eq. (1)
    return np.clip(v, 0.0, 1.0)


def eta_from_rest(d_rest: np.ndarray) -> float:
    """eta from the rest frames' deflection (deg): ETA_FACTOR times its ETA_QUANTILE
    quantile, at least :data:`ETA_FLOOR_DEG`.

    Raises
    ------
    ValueError
        No trusted (finite) rest frame.
    """
    d = np.abs(np.asarray(d_rest, float))
    d = d[np.isfinite(d)]
    if not d.size:
        raise ValueError("no trusted rest frame to measure the no-contact noise")
    return max(ETA_FACTOR * float(np.quantile(d, ETA_QUANTILE)), ETA_FLOOR_DEG)


def eta_source(d_rest: np.ndarray, eta: float) -> str:
    """How :func:`eta_from_rest` got ``eta`` from these rest frames, in words."""
    n = int(np.isfinite(np.asarray(d_rest, float)).sum())
    how = f"{ETA_FACTOR:g} x the {ETA_QUANTILE:g} quantile of phi_deg over {n} rest frame(s)"
    if eta == ETA_FLOOR_DEG:
        how = f"the floor {ETA_FLOOR_DEG:g} deg, above {how}"
    if n < MIN_REST_FRAMES:
        how += f"; fewer than {MIN_REST_FRAMES}: give --rest-frames N or --eta-deg X"
    return how


def next_contact(state: bool, b: float) -> bool:
    """The contact state after a frame of belief ``b``: entered at b = 1, left at b = 0,
    kept in between and where b is NaN (one frame of :func:`contact_flag`, for live use)."""
    if b >= 1.0:
        return True
    if b <= 0.0:
        return False
    return state


def contact_flag(b: np.ndarray) -> np.ndarray:
    """Per frame: in contact from where b reaches 1 until b falls to 0 (NaN keeps the state)."""
    flag = np.zeros(len(b), bool)
    state = False
    for i, x in enumerate(b):
        state = next_contact(state, x)
        flag[i] = state
    return flag


def _refine(d: np.ndarray, eta: float, detected: int, earliest: int) -> int:
    """The refined onset of a contact detected at ``detected`` (see the module's
    docstring), kept within [earliest, detected]."""
    first = detected  # first frame of the run above eta that leads to detection
    while first - 1 >= earliest and d[first - 1] > eta:
        first -= 1
    if first == detected:
        # A rise past eta in one frame: the onset is this frame or the one before,
        # which is in contact already if it stands above the rest noise's peak.
        before = first - 1
        in_contact = before >= earliest and d[before] > eta / ETA_FACTOR
        return before if in_contact else first
    k = np.arange(first, detected + 1)
    k = k[np.isfinite(d[k])]
    slope, intercept = np.polyfit(k, d[k], 1)
    if not slope > 0:
        return first
    zero = -intercept / slope
    # A linear rise from contact reaches eta no further from its zero than from eta to 2 eta.
    lowest = max(earliest, first - 1 - (detected - first + 1))
    return int(np.clip(math.floor(zero) + 1, lowest, detected))


def find_onsets(d: np.ndarray, eta: float) -> tuple[np.ndarray, np.ndarray, list[Onset]]:
    """Belief (eq. 1), contact flag and refined onsets of a deflection series.

    Parameters
    ----------
    d : ndarray, shape (N,)
        |d| per frame (NaN where untrusted).
    eta : float

    Returns
    -------
    b : ndarray, shape (N,)
    flag : ndarray of bool, shape (N,)
    onsets : list of Onset
    """
    d = np.abs(np.asarray(d, float))
    b = contact_belief(d, eta)
    flag = contact_flag(b)
    starts = np.flatnonzero(flag & ~np.r_[False, flag[:-1]])
    ends = np.flatnonzero(flag & ~np.r_[flag[1:], False])
    onsets, earliest = [], 0
    for start, end in zip(starts, ends, strict=True):
        onsets.append(Onset(_refine(d, eta, int(start), earliest), int(start), int(end)))
        earliest = int(end) + 1
    return b, flag, onsets
