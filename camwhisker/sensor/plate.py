"""The forward model: plate pose -> 3D feature points -> pixels.

This is the one model that the renderer draws and the front end inverts:
the features' geometry in the plate frame (the square, the cross, the rod and
its end face's rim, from the sensor file's ``[plate]`` table) and the plate's
rigid motion, projected by :mod:`camwhisker.sensor.camera`. :mod:`camwhisker.sensor.model`
caches it for the tracked points, with its Jacobians.

Plate frame (docs/sensor.md sections 2-3): origin at the centre of rotation, axes
parallel to the camera's at rest, z toward the whisker. A pose
(dz, phi, theta, sx, sy) maps a plate point p to the camera frame as::

    p_cam = R(phi, theta) p + (sx, sy, z_i - dz)

where R tilts the plate by phi about the in-plane axis a = (sin theta,
-cos theta, 0). This choice of axis moves the magnifier tip, p = (0, 0, -h_r),
to (h_r sin phi cos theta, h_r sin phi sin theta, z_i - dz - h_r cos phi):
theta is the image direction in which the tip moves, exactly as docs/sensor.md
section 2 defines it.

A real build's features may be glued off centre and rotated, and its rod
tilted (the sensor file's optional keys, docs/sensor.md section 5.1): every
feature function places its points accordingly, and returns the nominal
points, bit for bit, where those keys are zero.

The same motion has two forms: the matrix R of :func:`rotation_cam_from_plate`
(for 3D points and the renderer's rays) and the rotation vector of
:func:`rigid_motion`, phi (sin theta, -cos theta, 0), which
:func:`camwhisker.sensor.camera.project_rigid` takes with its Jacobian. The pose fit
works on the pose vector q = (dz_mm, a_rad, b_rad, sx_mm, sy_mm) with
a = phi cos(theta) and b = phi sin(theta): the tilt as a 2-vector, smooth
through phi = 0 where theta has no meaning; the rotation vector is (b, -a, 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from camwhisker.sensor.camera import JAC_RVEC, JAC_TVEC, project
from camwhisker.sensor.file import PlateConfig, Sensor

__all__ = [
    "Pose",
    "q_to_pose",
    "rigid_motion",
    "pose_jacobian",
    "rotation_cam_from_plate",
    "plate_to_camera",
    "square_corners",
    "cross_outline",
    "cross_arm_edges",
    "corner_edge_directions",
    "rod_ends",
    "rod_rims",
    "end_face_rim",
    "in_square",
    "in_cross",
    "in_cross_centre",
    "rod_frame",
    "feature_pixels",
    "ROD_RIM",
]

#: Points on each of the rod's end rims: its outline is their convex hull.
ROD_RIM = 24


@dataclass(frozen=True)
class Pose:
    """Plate pose. Angles in radians; see :meth:`from_degrees` for file units."""

    dz_mm: float = 0.0
    phi_rad: float = 0.0
    theta_rad: float = 0.0
    sx_mm: float = 0.0
    sy_mm: float = 0.0

    @classmethod
    def from_degrees(
        cls, dz_mm: float, phi_deg: float, theta_deg: float, sx_mm: float = 0.0, sy_mm: float = 0.0
    ) -> Pose:
        return cls(dz_mm, math.radians(phi_deg), math.radians(theta_deg), sx_mm, sy_mm)

    @property
    def phi_deg(self) -> float:
        return math.degrees(self.phi_rad)

    @property
    def theta_deg(self) -> float:
        return math.degrees(self.theta_rad)


def q_to_pose(q: np.ndarray) -> Pose:
    """Pose from the pose vector q = (dz_mm, a_rad, b_rad[, sx_mm, sy_mm])."""
    sx, sy = (q[3], q[4]) if len(q) > 3 else (0.0, 0.0)
    return Pose(float(q[0]), math.hypot(q[1], q[2]), math.atan2(q[2], q[1]), float(sx), float(sy))


def rigid_motion(q: np.ndarray, z_i_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """The plate's motion at pose vector q as (rvec, tvec) for
    :func:`camwhisker.sensor.camera.project_rigid`: rvec = (b, -a, 0) rad,
    tvec = (sx, sy, z_i - dz) mm. A 3-vector q has no shift."""
    q = np.asarray(q, dtype=float).tolist()  # Python floats: the same sums, no numpy calls
    sx, sy = (q[3], q[4]) if len(q) > 3 else (0.0, 0.0)
    return np.array([q[2], -q[1], 0.0]), np.array([sx, sy, z_i_mm - q[0]])


# project_rigid's Jacobian columns and signs that make d / d (dz, a, b, sx, sy),
# by the chain rule through rigid_motion.
_RVEC, _TVEC = JAC_RVEC.start, JAC_TVEC.start
_Q_COLUMNS = np.array([_TVEC + 2, _RVEC + 1, _RVEC, _TVEC, _TVEC + 1])
_Q_SIGNS = np.array([-1.0, -1.0, 1.0, 1.0, 1.0])


def pose_jacobian(jac: np.ndarray) -> np.ndarray:
    """:func:`camwhisker.sensor.camera.project_rigid`'s Jacobian, shape (..., 15), at the
    motion of :func:`rigid_motion` as d / d q = d / d (dz, a, b, sx, sy), (..., 5)."""
    return jac[..., _Q_COLUMNS] * _Q_SIGNS


def rotation_cam_from_plate(phi_rad: float, theta_rad: float) -> np.ndarray:
    """Rotation matrix of a tilt phi about the in-plane axis (sin theta, -cos theta, 0).

    Rodrigues' formula, written out: for a unit axis a with a_z = 0,
    R = cos(phi) I + sin(phi) [a]_x + (1 - cos(phi)) a a^T.
    """
    ax, ay = math.sin(theta_rad), -math.cos(theta_rad)
    c, s = math.cos(phi_rad), math.sin(phi_rad)
    v = 1.0 - c
    return np.array(
        [
            [c + v * ax * ax, v * ax * ay, s * ay],
            [v * ax * ay, c + v * ay * ay, -s * ax],
            [-s * ay, s * ax, c],
        ]
    )


def plate_to_camera(points_in_plate: np.ndarray, pose: Pose, plate: PlateConfig) -> np.ndarray:
    """Points in the plate frame, shape (..., 3), to the camera frame, same shape."""
    rot = rotation_cam_from_plate(pose.phi_rad, pose.theta_rad)
    shift = np.array([pose.sx_mm, pose.sy_mm, plate.z_i_mm - pose.dz_mm])
    return np.asarray(points_in_plate, dtype=float) @ rot.T + shift


def square_corners(plate: PlateConfig) -> np.ndarray:
    """Corners of the blue square, shape (4, 3), in image order at rest:
    top-left, top-right, bottom-right, bottom-left."""
    h = plate.square_side_mm / 2
    z = plate.square_offset_mm
    return _place(np.array([[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]]), *_square_at(plate))


def _square_at(plate: PlateConfig) -> tuple[float, float, float]:
    return plate.square_shift_x_mm, plate.square_shift_y_mm, plate.square_rotation_deg


def _cross_at(plate: PlateConfig) -> tuple[float, float, float]:
    return plate.cross_shift_x_mm, plate.cross_shift_y_mm, plate.cross_rotation_deg


def _place(points: np.ndarray, dx_mm: float, dy_mm: float, rotation_deg: float) -> np.ndarray:
    """Feature points (..., 3) as glued: rotated in-plane about the feature's centre,
    then shifted. The nominal placement returns the points themselves, bit for bit."""
    if dx_mm == 0.0 and dy_mm == 0.0 and rotation_deg == 0.0:
        return points
    c, s = math.cos(math.radians(rotation_deg)), math.sin(math.radians(rotation_deg))
    out = np.array(points, dtype=float)
    x, y = out[..., 0].copy(), out[..., 1]
    out[..., 0] = c * x - s * y + dx_mm
    out[..., 1] = s * x + c * y + dy_mm
    return out


def _unplace(x, y, dx_mm: float, dy_mm: float, rotation_deg: float):
    """Inverse of :func:`_place` for plate coordinates: the feature's own (x, y)."""
    if dx_mm == 0.0 and dy_mm == 0.0 and rotation_deg == 0.0:
        return x, y
    c, s = math.cos(math.radians(rotation_deg)), math.sin(math.radians(rotation_deg))
    x, y = x - dx_mm, y - dy_mm
    return c * x + s * y, -s * x + c * y


def cross_outline(plate: PlateConfig) -> np.ndarray:
    """The red cross as a closed 12-vertex polygon, shape (12, 3), clockwise in the image."""
    s, a = plate.cross_span_mm / 2, plate.cross_arm_mm / 2
    z = -plate.cross_offset_mm
    xy = [
        (-a, -s), (a, -s), (a, -a), (s, -a), (s, a), (a, a),
        (a, s), (-a, s), (-a, a), (-s, a), (-s, -a), (-a, -a),
    ]  # fmt: skip
    return _place(np.array([(x, y, z) for x, y in xy]), *_cross_at(plate))


def cross_arm_edges(plate: PlateConfig) -> np.ndarray:
    """The outer (end) edge of each arm, shape (4, 2, 3): arms +x, +y, -x, -y, each
    edge as its two end points. These are the paper's tracked cross edges."""
    s, a = plate.cross_span_mm / 2, plate.cross_arm_mm / 2
    z = -plate.cross_offset_mm
    edges = np.array(
        [
            [[s, -a, z], [s, a, z]],
            [[a, s, z], [-a, s, z]],
            [[-s, a, z], [-s, -a, z]],
            [[-a, -s, z], [a, -s, z]],
        ]
    )
    return _place(edges, *_cross_at(plate))


def corner_edge_directions(plate: PlateConfig) -> np.ndarray:
    """Directions of the two edges leaving each tracked corner, shape (12, 2, 3), not
    normalised: the square's 4 corners, then the arm ends' 8 (arms +x, +y, -x, -y,
    two corners each, as :func:`cross_arm_edges`): along the end edge, then inward."""
    sq = square_corners(plate)
    sq_dirs = np.stack([np.roll(sq, 1, axis=0) - sq, np.roll(sq, -1, axis=0) - sq], axis=1)
    arm = cross_arm_edges(plate)
    inward = np.array([[-1.0, 0, 0], [0, -1.0, 0], [1.0, 0, 0], [0, 1.0, 0]])
    inward = _place(inward, 0.0, 0.0, plate.cross_rotation_deg)
    cr_dirs = [[end[1 - i] - end[i], inward[j]] for j, end in enumerate(arm) for i in (0, 1)]
    return np.concatenate([sq_dirs, np.array(cr_dirs)], axis=0)


def rod_frame(plate: PlateConfig) -> tuple[np.ndarray | None, np.ndarray | None, float]:
    """The rod's own frame, in which it stands along z from its base on the cross,
    (0, 0, -cross_offset), to its end face at z = z_tip.

    Returns
    -------
    rotation : ndarray, shape (3, 3), or None
    origin_mm : ndarray, shape (3,), or None
        A rod point p maps to the plate frame as rotation @ p + origin_mm; both
        are None for the nominal rod, whose frame is the plate's.
    z_tip_mm : float
        The end face's z in the rod's frame; -h_r for the nominal rod.

    The rod stands on the cross's centre (so it moves with the cross's shift);
    a tilted rod's end face is square to the rod and its centre lies at
    (tip_offset_x, tip_offset_y, -h_r) from the cross's centre.
    """
    dx, dy = plate.cross_shift_x_mm, plate.cross_shift_y_mm
    ox, oy = plate.tip_offset_x_mm, plate.tip_offset_y_mm
    if dx == 0.0 and dy == 0.0 and ox == 0.0 and oy == 0.0:
        return None, None, -plate.h_r_mm
    axis = np.array([ox, oy, plate.h_r_mm - plate.cross_offset_mm])  # base to tip, reversed z
    length = float(np.linalg.norm(axis))
    w = np.array([ox, oy, -axis[2]]) / length  # the rod's direction from its base, plate frame
    # Rotation that takes (0, 0, -1) to w, about the axis perpendicular to both.
    k = np.cross([0.0, 0.0, -1.0], w)
    s, c = float(np.linalg.norm(k)), float(-w[2])
    rotation = np.eye(3)
    if s > 0.0:
        k /= s
        kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        rotation = np.eye(3) + s * kx + (1.0 - c) * kx @ kx
    base = np.array([dx, dy, -plate.cross_offset_mm])
    origin = base - rotation @ np.array([0.0, 0.0, -plate.cross_offset_mm])
    return rotation, origin, -plate.cross_offset_mm - length


def _rod_to_plate(plate: PlateConfig, points: np.ndarray) -> np.ndarray:
    rotation, origin, _ = rod_frame(plate)
    return points if rotation is None else points @ rotation.T + origin


def rod_ends(plate: PlateConfig) -> np.ndarray:
    """Rod axis end points, shape (2, 3): its base on the cross, and the tip's centre."""
    z_tip = rod_frame(plate)[2]
    return _rod_to_plate(plate, np.array([[0.0, 0.0, -plate.cross_offset_mm], [0.0, 0.0, z_tip]]))


def _ring(plate: PlateConfig, n: int) -> np.ndarray:
    ang = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    rho = plate.rod_diameter_mm / 2
    return np.column_stack([rho * np.cos(ang), rho * np.sin(ang)])


def rod_rims(plate: PlateConfig, n: int = ROD_RIM) -> np.ndarray:
    """The rod's two end rims, shape (2 n, 3): n points on the rim at its base on
    the cross, then n on the rim at the tip."""
    ring = _ring(plate, n)
    z_tip = rod_frame(plate)[2]
    rims = np.concatenate(
        [np.column_stack([ring, np.full(n, z)]) for z in (-plate.cross_offset_mm, z_tip)]
    )
    return _rod_to_plate(plate, rims)


def end_face_rim(plate: PlateConfig, n: int) -> np.ndarray:
    """n points on the rim of the rod's end face (the magnifier tip), shape (n, 3)."""
    z_tip = rod_frame(plate)[2]
    return _rod_to_plate(plate, np.column_stack([_ring(plate, n), np.full(n, z_tip)]))


def in_square(x: np.ndarray, y: np.ndarray, plate: PlateConfig) -> np.ndarray:
    """Whether plate points (x, y) in the square's plane lie on the square."""
    h = plate.square_side_mm / 2
    x, y = _unplace(x, y, *_square_at(plate))
    return (np.abs(x) <= h) & (np.abs(y) <= h)


def in_cross(x: np.ndarray, y: np.ndarray, plate: PlateConfig) -> np.ndarray:
    """Whether plate points (x, y) in the cross's plane lie on the cross."""
    s, a = plate.cross_span_mm / 2, plate.cross_arm_mm / 2
    x, y = _unplace(x, y, *_cross_at(plate))
    ax, ay = np.abs(x), np.abs(y)
    return ((ax <= a) & (ay <= s)) | ((ax <= s) & (ay <= a))


def in_cross_centre(x: np.ndarray, y: np.ndarray, plate: PlateConfig, radius_mm: float):
    """Whether plate points (x, y) in the cross's plane lie within radius_mm of its centre."""
    x, y = _unplace(x, y, *_cross_at(plate))
    return x * x + y * y <= radius_mm * radius_mm


def feature_pixels(pose: Pose, sensor: Sensor) -> dict[str, np.ndarray]:
    """Image positions of every tracked feature for one pose.

    Returns
    -------
    dict
        ``square_corners`` (4, 2), ``cross_arm_edges`` (4, 2, 2),
        ``cross_outline`` (12, 2), ``tip`` (2,): pixel (u, v) of each point.
    """
    plate = sensor.plate
    pts = {
        "square_corners": square_corners(plate),
        "cross_arm_edges": cross_arm_edges(plate),
        "cross_outline": cross_outline(plate),
        "tip": rod_ends(plate)[1],
    }
    return {k: project(plate_to_camera(p, pose, plate), sensor.camera) for k, p in pts.items()}
