"""Pose logs (docs/sensor.md section 9): the sensor frame S in the world frame W over time.

A pose log is a CSV ``t_s,x_mm,y_mm,z_mm,qw,qx,qy,qz`` on the pose source's own clock, one
row per sample: a point p_S of S lies at R(q) p_S + (x_mm, y_mm, z_mm) in W, q a unit
quaternion, scalar first (ROS's geometry_msgs, scipy's ``scalar_first=True``). Where the
log gives the pose of a carrier (a robot's flange, a rig), the sensor's mount is the pose
of S in the carrier's frame: the sensor's pose in W is the carrier's composed with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from camwhisker.files.tables import check_times, read_log

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation

__all__ = ["POSE_COLUMNS", "MAX_GAP_S", "QUAT_NORM_TOL", "PoseLogError", "Mount", "PoseLog",
           "read_pose_log", "pose_log_from_arrays"]  # fmt: skip

POSE_COLUMNS = ("t_s", "x_mm", "y_mm", "z_mm", "qw", "qx", "qy", "qz")
#: Longest interval between samples (s): a longer gap could hide a motion.
MAX_GAP_S = 1.0
#: How far a quaternion's norm may be from 1: a log's rounding, not a wrong convention.
QUAT_NORM_TOL = 1e-3


def _rotations(quat: np.ndarray) -> Rotation:
    # scipy.spatial takes ~0.25 s to import: every command line builds its parser from
    # modules that import this one.
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(quat, scalar_first=True)


class PoseLogError(ValueError):
    """A pose log or mount that cannot be used; the message names the file, row and column."""


@dataclass(frozen=True)
class Mount:
    """A rigid pose: ``position_mm`` (3,) and unit quaternion ``quat`` (4,), scalar first."""

    position_mm: np.ndarray
    quat: np.ndarray

    @classmethod
    def parse(cls, text: str) -> Mount:
        """``X,Y,Z,QW,QX,QY,QZ`` (mm, then a unit quaternion, scalar first)."""
        try:
            v = [float(c) for c in text.split(",")]
        except ValueError:
            v = []
        if len(v) != 7 or not all(math.isfinite(c) for c in v):
            raise PoseLogError(f"mount {text!r}: expected X,Y,Z,QW,QX,QY,QZ (seven numbers)")
        norm = math.sqrt(sum(c * c for c in v[3:]))
        if abs(norm - 1.0) > QUAT_NORM_TOL:
            raise PoseLogError(f"mount {text!r}: the quaternion's norm is {norm:.6g}, "
                               f"not 1 (within {QUAT_NORM_TOL:g})")  # fmt: skip
        return cls(np.array(v[:3]), np.array(v[3:]) / norm)

    @property
    def rotation(self) -> Rotation:
        return _rotations(self.quat)


@dataclass(frozen=True)
class PoseLog:
    """A validated pose log: ``t_s`` (N,) strictly increasing, ``p_mm`` (N, 3), ``quat``
    (N, 4) unit, scalar first; the pose of S in W (a mount already applied)."""

    t_s: np.ndarray
    p_mm: np.ndarray
    quat: np.ndarray
    source: str

    @property
    def rotations(self) -> Rotation:
        return _rotations(self.quat)

    def mounted(self, mount: Mount | None) -> PoseLog:
        """The sensor's poses where this log gives its carrier's: carrier composed with mount."""
        if mount is None:
            return self
        r = self.rotations
        p = self.p_mm + r.apply(mount.position_mm)
        q = (r * mount.rotation).as_quat(scalar_first=True)
        return PoseLog(self.t_s, p, q, f"{self.source} (mounted)")

    def at(self, t_pose_s) -> tuple[np.ndarray, np.ndarray]:
        """Position (M, 3) and rotation matrix (M, 3, 3) at pose-clock times: position
        linear, rotation by slerp between samples; NaN outside the log."""
        t = np.atleast_1d(np.asarray(t_pose_s, float))
        inside = np.isfinite(t) & (t >= self.t_s[0]) & (t <= self.t_s[-1])
        p = np.full((t.size, 3), np.nan)
        m = np.full((t.size, 3, 3), np.nan)
        if inside.any():
            ti = t[inside]
            p[inside] = np.column_stack([np.interp(ti, self.t_s, self.p_mm[:, k])
                                         for k in range(3)])  # fmt: skip
            from scipy.spatial.transform import Slerp

            m[inside] = Slerp(self.t_s, self.rotations)(ti).as_matrix()
        return p, m

    def motion_mm(self, reach_mm: float) -> np.ndarray:
        """The base's motion per interval (N - 1, 6), mm: its translation in W, then its
        turn (a rotation vector in S) times ``reach_mm``, the path of a shaft's point that
        far out; a pause is where both stand still."""
        r = self.rotations
        turn = (r[:-1].inv() * r[1:]).as_rotvec()
        return np.column_stack([np.diff(self.p_mm, axis=0), reach_mm * turn])

    def turn_deg(self) -> float:
        """The largest angle (deg) between the first sample's orientation and any other's."""
        rel = self.rotations[0].inv() * self.rotations
        return float(np.degrees(np.max(rel.magnitude())))


def pose_log_from_arrays(t_s, p_mm, quat, source: str = "<arrays>", rows=None,
                         max_gap_s: float = MAX_GAP_S) -> PoseLog:  # fmt: skip
    """Check arrays as a pose log (see :func:`read_pose_log`); ``rows`` numbers each
    sample as its file does (default: from 2, under a header)."""
    t = np.asarray(t_s, float)
    p = np.asarray(p_mm, float).reshape(-1, 3)
    q = np.asarray(quat, float).reshape(-1, 4)
    rows = list(rows) if rows is not None else list(range(2, 2 + t.size))
    if t.size < 2:
        raise PoseLogError(f"{source}: needs at least 2 samples, got {t.size}")
    if p.shape[0] != t.size or q.shape[0] != t.size:
        raise PoseLogError(f"{source}: columns have different lengths")
    for name, v in (("t_s", t), ("x_mm", p[:, 0]), ("y_mm", p[:, 1]), ("z_mm", p[:, 2]),
                    ("qw", q[:, 0]), ("qx", q[:, 1]), ("qy", q[:, 2]), ("qz", q[:, 3])):
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            raise PoseLogError(f"{source}: row {rows[bad[0]]}, column {name}: not a finite number")
    check_times(t, rows, source, max_gap_s, PoseLogError)
    norm = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(np.abs(norm - 1.0) > QUAT_NORM_TOL)
    if bad.size:
        k = bad[0]
        raise PoseLogError(f"{source}: row {rows[k]}, columns qw-qz: the quaternion's norm is "
                           f"{norm[k]:.6g}, not 1 (within {QUAT_NORM_TOL:g}; scalar first, "
                           "docs/sensor.md section 9)")  # fmt: skip
    return PoseLog(t, p, q / norm[:, None], source)


def read_pose_log(path: str | Path, mount: Mount | None = None) -> PoseLog:
    """Read and check a pose log; with ``mount``, the sensor's poses from its carrier's.

    ``path`` may name a topic of an MCAP bag, ``FILE.mcap:/topic``, of ROS 2 PoseStamped
    or TransformStamped messages (:func:`camwhisker.io.bag.read_pose_bag`; the extra
    ``ros``): in metres there, read into mm.

    Raises
    ------
    PoseLogError
        A missing file or column, a cell not a finite number, times not strictly
        increasing, a gap over :data:`MAX_GAP_S`, a quaternion whose norm is not 1
        within :data:`QUAT_NORM_TOL`, fewer than two rows. The message names the file,
        the 1-based row (the header is row 1) and the column; for a bag, ``FILE:TOPIC``
        and the message counted from 1 (a missing topic lists the bag's).
    """
    # Imported here: bag.py imports this module (and mcap only where a bag is read).
    from camwhisker.io.bag import bag_source, read_pose_bag

    bag = bag_source(path, PoseLogError)
    if bag is not None:
        return read_pose_bag(*bag).mounted(mount)
    data, rows = read_log(path, POSE_COLUMNS, (), "pose log", PoseLogError)
    p = np.column_stack([data["x_mm"], data["y_mm"], data["z_mm"]])
    q = np.column_stack([data["qw"], data["qx"], data["qy"], data["qz"]])
    return pose_log_from_arrays(data["t_s"], p, q, str(path), rows).mounted(mount)
