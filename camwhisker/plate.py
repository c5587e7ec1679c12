"""The forward model: plate pose -> 3D feature points -> pixels.

This is the one model that the renderer draws and the front end inverts.

Plate frame (SENSOR.md sections 2-3): origin at the centre of rotation, axes
parallel to the camera's at rest, z toward the whisker. A pose
(dz, phi, theta, sx, sy) maps a plate point p to the camera frame as::

    p_cam = R(phi, theta) p + (sx, sy, z_i - dz)

where R tilts the plate by phi about the in-plane axis a = (sin theta,
-cos theta, 0). This choice of axis moves the magnifier tip, p = (0, 0, -h_r),
to (h_r sin phi cos theta, h_r sin phi sin theta, z_i - dz - h_r cos phi):
theta is the image direction in which the tip moves, exactly as SENSOR.md
section 2 defines it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from camwhisker.camera import project
from camwhisker.sensor import PlateConfig, Sensor

__all__ = [
    "Pose",
    "rotation_cam_from_plate",
    "plate_to_camera",
    "square_corners",
    "cross_outline",
    "cross_arm_edges",
    "rod_ends",
    "feature_pixels",
]


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
    return np.array([[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]])


def cross_outline(plate: PlateConfig) -> np.ndarray:
    """The red cross as a closed 12-vertex polygon, shape (12, 3), clockwise in the image."""
    s, a = plate.cross_span_mm / 2, plate.cross_arm_mm / 2
    z = -plate.cross_offset_mm
    xy = [
        (-a, -s), (a, -s), (a, -a), (s, -a), (s, a), (a, a),
        (a, s), (-a, s), (-a, a), (-s, a), (-s, -a), (-a, -a),
    ]  # fmt: skip
    return np.array([(x, y, z) for x, y in xy])


def cross_arm_edges(plate: PlateConfig) -> np.ndarray:
    """The outer (end) edge of each arm, shape (4, 2, 3): arms +x, +y, -x, -y, each
    edge as its two end points. These are the paper's tracked cross edges."""
    s, a = plate.cross_span_mm / 2, plate.cross_arm_mm / 2
    z = -plate.cross_offset_mm
    return np.array(
        [
            [[s, -a, z], [s, a, z]],
            [[a, s, z], [-a, s, z]],
            [[-s, a, z], [-s, -a, z]],
            [[-a, -s, z], [a, -s, z]],
        ]
    )


def rod_ends(plate: PlateConfig) -> np.ndarray:
    """Rod axis end points, shape (2, 3): its base on the cross, and the tip's centre."""
    return np.array([[0.0, 0.0, -plate.cross_offset_mm], [0.0, 0.0, -plate.h_r_mm]])


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
