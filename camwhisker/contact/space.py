"""Contact in 3-D (docs/sensor.md section 9): a base that moves in space, contacts placed in W.

The whisker bends in the plane of its shaft and the contact force; theta (signals) says
which way the base pressed into the object. So the contact side of a one-axis stage
applies along that direction: the base's travel across the shaft toward theta, read
from the pose log, is the stage position (:func:`travel_log`); GM, MF, Z, the fusion and
eq. 12 run as for a stage (:func:`~camwhisker.contact.pipeline.contact_rows`), and eq.
12's point, in the plane of the shaft and theta, is placed in W by the base's pose at
the frame (:func:`contact_rows_in_space`).

In S (section 9): the whisker at rest lies along z_S; a tilt toward psi = theta + 180 deg
is the object's push, so (cos psi, sin psi, 0) is the estimate of the surface normal.
The base must keep its orientation over a run (within :data:`MAX_TURN_DEG`): a turning
base moves each point of the shaft differently, which GM's single travel cannot hold.
"""

from __future__ import annotations

import math

import numpy as np

from camwhisker.contact.pipeline import CONTACT_COLUMNS, Calibration, RunAnalysis, contact_rows
from camwhisker.contact.stage import CONTACT_PHI_DEG, StageLog, stage_log_from_arrays
from camwhisker.io.poses import MAX_GAP_S, PoseLog

__all__ = ["WORLD_COLUMNS", "BASE_COLUMNS", "MAX_TURN_DEG", "MIN_TRAVEL_MM", "SpaceError",
           "pressing_theta_deg", "travel_log", "contact_rows_in_space"]  # fmt: skip

#: The contact point and the surface normal's estimate in W, after the section 7 columns.
WORLD_COLUMNS = ("px_mm", "py_mm", "pz_mm", "nx", "ny", "nz")
#: Written after them: the base (S's origin) in W and the shaft's rest direction (z_S), for
#: the free space the base moved through and the normal's component along the shaft.
BASE_COLUMNS = ("bx_mm", "by_mm", "bz_mm", "ax", "ay", "az")
#: Largest turn of the base over a run (deg): at the whisker's 100 mm it moves the shaft's
#: point by 0.9 mm, about GM's spread; more needs the turning base's own model.
MAX_TURN_DEG = 0.5
#: Least range of the base's travel across the shaft (mm): one of the calibration's steps.
MIN_TRAVEL_MM = 1.0


class SpaceError(ValueError):
    """A run that cannot be placed in space; the message names the file and why."""


def pressing_theta_deg(signals: dict) -> float:
    """The direction theta (deg, in S) in which the base pressed: the circular mean of the
    trusted rows' theta in contact (phi >= CONTACT_PHI_DEG), each weighted by its phi; NaN
    without such a row."""
    theta = np.asarray(signals["theta_deg"], float)
    phi = np.asarray(signals["phi_deg"], float)
    use = np.asarray(signals["ok"], bool) & (phi >= CONTACT_PHI_DEG) & np.isfinite(theta)
    if not use.any():
        return math.nan
    t = np.radians(theta[use])
    return float(np.degrees(np.arctan2(np.sum(phi[use] * np.sin(t)),
                                       np.sum(phi[use] * np.cos(t)))))  # fmt: skip


def _direction_s(theta_deg: float) -> np.ndarray:
    th = math.radians(theta_deg)
    return np.array([math.cos(th), math.sin(th), 0.0])


def travel_log(poses: PoseLog, theta_deg: float) -> StageLog:
    """The base's position along theta, across the shaft, as a one-axis stage log.

    Raises
    ------
    SpaceError
        The base turns by more than :data:`MAX_TURN_DEG`, or never moves across the
        shaft toward theta by :data:`MIN_TRAVEL_MM`.
    """
    turn = poses.turn_deg()
    if turn > MAX_TURN_DEG:
        raise SpaceError(f"{poses.source}: the base turns by {turn:.2f} deg over the run; "
                         f"contact is placed for a base that keeps its orientation (within "
                         f"{MAX_TURN_DEG:g} deg)")  # fmt: skip
    d_w = poses.rotations[0].apply(_direction_s(theta_deg))
    x = (poses.p_mm - poses.p_mm[0]) @ d_w
    if np.ptp(x) < MIN_TRAVEL_MM:
        raise SpaceError(f"{poses.source}: the base never moves across the shaft toward "
                         f"theta {theta_deg:.1f} deg (it travels {np.ptp(x):.2f} mm that way, "
                         f"less than {MIN_TRAVEL_MM:g} mm): GM has no travel to work from")
    return stage_log_from_arrays(poses.t_s, x, source=f"{poses.source} (travel toward theta)",
                                 max_gap_s=MAX_GAP_S, first_row=2)  # fmt: skip


def contact_rows_in_space(signals: dict, poses: PoseLog, calib: Calibration,
                          offset_s: float | None = None, mode: str = "frame"
                          ) -> tuple[dict, RunAnalysis, float]:  # fmt: skip
    """The contact table of a run whose base moves in space, with :data:`WORLD_COLUMNS`.

    ``x_mm`` is the base's position along theta (from its first pose) and ``dx_mm`` its
    travel since first contact; ``offset_s`` is the pose clock's (t_camera = t_pose +
    offset), estimated from the base's pauses unless given. Returns the columns, the run's
    analysis and the pressing direction theta (deg).

    Raises
    ------
    SpaceError
        No trusted row in contact (theta unknown), or see :func:`travel_log`.
    """
    theta = pressing_theta_deg(signals)
    if not math.isfinite(theta):
        raise SpaceError(f"{signals.get('source', '<signals>')}: no trusted row with phi >= "
                         f"{CONTACT_PHI_DEG:g} deg: the direction the base pressed in is "
                         "unknown")  # fmt: skip
    cols, run = contact_rows(signals, travel_log(poses, theta), calib, offset_s, mode)
    p, m = poses.at(np.asarray(cols["t_s"], float) - run.offset_s)
    d_s = _direction_s(theta)
    lateral = np.asarray(cols["x_hat_mm"], float) - np.asarray(cols["x_mm"], float)
    # Eq. 12's point: across the shaft along theta (behind the base), along it on z_S.
    local = lateral[:, None] * d_s + np.asarray(cols["y_hat_mm"], float)[:, None] * [0, 0, 1]
    point = p + np.einsum("nij,nj->ni", m, local)
    normal = np.einsum("nij,j->ni", m, -d_s)
    normal[~np.isfinite(point).all(axis=1)] = np.nan
    shaft = m[:, :, 2]
    world = dict(zip(WORLD_COLUMNS + BASE_COLUMNS, [*point.T, *normal.T, *p.T, *shaft.T],
                     strict=True))  # fmt: skip
    n = len(CONTACT_COLUMNS)
    names = list(cols)
    return {**{k: cols[k] for k in names[:n]}, **world,
            **{k: cols[k] for k in names[n:]}}, run, theta  # fmt: skip
