"""The forward model of the tracked points, cached per sensor, with its Jacobians.

:class:`PlateModel` holds the plate-frame points of :mod:`camwhisker.sensor.plate`
that the front end tracks or draws, and projects them at a pose vector
q = (dz_mm, a_rad, b_rad, sx_mm, sy_mm) through
:func:`camwhisker.sensor.camera.project_rigid`: the model that detection, the tip's
measurement and the pose fit all invert.

Tracked points (``POINT_NAMES``): the square's 4 corners, the 8 outer corners
of the cross's arm ends, and the magnifier tip. The tip's image is the end
face's centroid; its model value is the area centroid of the projected rim
circle (the projection of a disc's centre is not its image's centroid).

Jacobians: :meth:`PlateModel.project` gives d uv / d q, the hot path's
(its tip row is the disc centre's); :meth:`PlateModel.jacobians` gives the
exact d uv / d q and d uv / d geometry, the camera intrinsics and every
dimension of the ``[plate]`` table (``GEOMETRY_NAMES``; its optional keys, a
build's misplacements and rod tilt, included), for calibration
(:meth:`PlateModel.jacobians_many`: at many poses at once). A
key added to that table joins the geometry by itself once
:func:`tracked_object_points` depends on it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

from camwhisker.sensor.camera import INTRINSIC_NAMES, JAC_INTRINSICS, JAC_TVEC, project_rigid
from camwhisker.sensor.file import PlateConfig, Sensor
from camwhisker.sensor.plate import (
    corner_edge_directions,
    cross_arm_edges,
    cross_outline,
    end_face_rim,
    pose_jacobian,
    rigid_motion,
    rod_ends,
    rod_rims,
    square_corners,
)
from camwhisker.sensor.polygon import polygon_centroid, polygon_centroid_jacobian

__all__ = [
    "POINT_NAMES",
    "N_SQUARE",
    "N_CROSS",
    "TIP",
    "N_RIM",
    "GEOMETRY_NAMES",
    "BUILD_TOLERANCE",
    "ROD_TILT_TOLERANCE_DEG",
    "RELATIVE_TOLERANCE",
    "build_tolerances",
    "PlateModel",
    "ModelJacobians",
    "tracked_object_points",
    "geometry_vector",
    "with_geometry",
]

POINT_NAMES = (
    [f"square_{c}" for c in ("tl", "tr", "br", "bl")]
    + [f"cross_{arm}_{k}" for arm in ("px", "py", "mx", "my") for k in (0, 1)]
    + ["tip"]
)
N_SQUARE = 4
N_CROSS = 8
#: Index of the tip in the point arrays.
TIP = N_SQUARE + N_CROSS

#: Points on the rim of the end face used for its projected centroid. With 64 the
#: polygon's centroid differs from the ellipse's by < 1e-4 px at phi = 35 deg.
N_RIM = 64

_PLATE_KEYS = tuple(f.name for f in dataclasses.fields(PlateConfig))
#: The geometry parameters of :meth:`PlateModel.jacobians`, as "table.key" of the
#: sensor file; camera.k1 ... camera.k3 are the entries of its distortion list.
GEOMETRY_NAMES = tuple(f"camera.{k}" for k in INTRINSIC_NAMES) + tuple(
    f"plate.{k}" for k in _PLATE_KEYS
)
#: docs/sensor.md section 8: a hand build's rod may be glued this far off perpendicular.
ROD_TILT_TOLERANCE_DEG = 2.0
#: docs/sensor.md section 8: how far a hand build's value of each geometry parameter
#: may lie from the nominal file's (fx, fy relative; p1, p2 by analogy with k1; the
#: rod's tilt moves the tip by h_r tan(ROD_TILT_TOLERANCE_DEG), ~0.26 mm).
BUILD_TOLERANCE = {
    "camera.fx_px": 0.04, "camera.fy_px": 0.04, "camera.cx_px": 10.0, "camera.cy_px": 10.0,
    "camera.k1": 0.1, "camera.k2": 0.1, "camera.p1": 0.005, "camera.p2": 0.005,
    "camera.k3": 0.1, "plate.z_i_mm": 0.6, "plate.h_r_mm": 0.3,
    "plate.square_side_mm": 0.1, "plate.square_offset_mm": 0.2, "plate.cross_span_mm": 0.1,
    "plate.cross_arm_mm": 0.1, "plate.cross_offset_mm": 0.2, "plate.rod_diameter_mm": 0.1,
    "plate.tip_offset_x_mm": 0.26, "plate.tip_offset_y_mm": 0.26,
    "plate.square_shift_x_mm": 0.3, "plate.square_shift_y_mm": 0.3,
    "plate.square_rotation_deg": 3.0, "plate.cross_shift_x_mm": 0.3,
    "plate.cross_shift_y_mm": 0.3, "plate.cross_rotation_deg": 3.0,
}  # fmt: skip
#: The parameters whose tolerance is relative to their value.
RELATIVE_TOLERANCE = ("camera.fx_px", "camera.fy_px")
#: Central-difference half-step (mm, or deg for a rotation) of the plate points'
#: derivatives by the plate dimensions: the points are linear in all but the
#: optional rotations and tip offset, where the error is O(step^2), ~1e-7 relative.
_PLATE_STEP_MM = 1e-3


def tracked_object_points(plate: PlateConfig) -> np.ndarray:
    """Plate-frame points projected for the tracked points, shape (TIP + 1 + N_RIM, 3):
    the 12 tracked corners, the tip's centre, then the end face's rim."""
    return np.concatenate(
        [square_corners(plate), cross_arm_edges(plate).reshape(-1, 3), rod_ends(plate)[1:],
         end_face_rim(plate, N_RIM)]
    )  # fmt: skip


@dataclass(frozen=True)
class ModelJacobians:
    """The tracked points' model pixels and their exact derivatives (tip = face centroid).

    uv : ndarray, shape (13, 2)
    pose : ndarray, shape (13, 2, 5)
        d uv / d q, q = (dz_mm, a_rad, b_rad, sx_mm, sy_mm).
    geometry : ndarray, shape (13, 2, len(GEOMETRY_NAMES))
        d uv / d the geometry parameters of ``GEOMETRY_NAMES``.
    corner_point : ndarray, shape (12, 2, 3)
        d uv / d each tracked corner's position in the plate frame.
    """

    uv: np.ndarray
    pose: np.ndarray
    geometry: np.ndarray
    corner_point: np.ndarray


class PlateModel:
    """The forward model of :mod:`camwhisker.sensor.plate` for the tracked points, with Jacobian.

    Parameters
    ----------
    sensor : Sensor
    """

    def __init__(self, sensor: Sensor):
        self.sensor = sensor
        plate = sensor.plate
        #: Plate-frame points: 12 tracked corners, the tip centre, the rim.
        self.object_points = np.ascontiguousarray(tracked_object_points(plate))
        self._tip_points = self.object_points[TIP:]  # the face's centre, then its rim
        self._corner_points = np.ascontiguousarray(self.object_points[:TIP])
        self._edge_dirs_plate = corner_edge_directions(plate)
        #: The corners and points step_mm along their edges, by step_mm (see edge_directions).
        self._edge_points: dict[float, np.ndarray] = {}
        # Plate-frame outlines (see outlines()): the end face's rim, the rod's two
        # end rims, the cross.
        self._outline_points = np.ascontiguousarray(
            np.concatenate([end_face_rim(plate, N_RIM), rod_rims(plate), cross_outline(plate)])
        )
        self._rod_end = N_RIM + len(rod_rims(plate))
        self.camera = sensor.camera
        self.z_i_mm = plate.z_i_mm

    def edge_directions(self, q: np.ndarray, step_mm: float = 0.05) -> np.ndarray:
        """Image directions of the two edges leaving each of the 12 corners, (12, 2, 2)."""
        pts = self._edge_points.get(step_mm)
        if pts is None:
            corners = self.object_points[:TIP]
            d = self._edge_dirs_plate / np.linalg.norm(self._edge_dirs_plate, axis=-1,
                                                       keepdims=True)  # fmt: skip
            pts = np.concatenate([corners, (corners[:, None] + step_mm * d).reshape(-1, 3)])
            self._edge_points[step_mm] = pts
        uv = self._project(pts, q)[0]
        return uv[TIP:].reshape(TIP, 2, 2) - uv[:TIP, None]

    def outlines(self, q: np.ndarray):
        """The end face's rim (N_RIM, 2), the rod's two end rims (2 ROD_RIM, 2;
        their convex hull is the rod's outline) and the cross's outline (12, 2)
        in the image at pose q, from one projection."""
        uv = self._project(self._outline_points, q)[0]
        return uv[:N_RIM], uv[N_RIM : self._rod_end], uv[self._rod_end :]

    def covers(self, q: np.ndarray):
        """The rod's two end rims and the cross's outline of :meth:`outlines` alone
        (what may cover a corner), from one projection of those points."""
        uv = self._project(self._outline_points[N_RIM:], q)[0]
        return uv[: self._rod_end - N_RIM], uv[self._rod_end - N_RIM :]

    def _project(self, pts: np.ndarray, q: np.ndarray):
        """Plate-frame points (n, 3) at pose q: pixels (n, 2) and project_rigid's
        Jacobian (2 n, 15)."""
        rvec, tvec = rigid_motion(q, self.z_i_mm)
        return project_rigid(pts, rvec, tvec, self.camera)

    def corners(self, q: np.ndarray) -> np.ndarray:
        """The 12 tracked corners' rows of :meth:`project` alone, shape (12, 2), from
        one projection of those points."""
        return self._project(self._corner_points, q)[0]

    def tip(self, q: np.ndarray):
        """The tip's row of :meth:`project` alone, from one smaller projection: the
        face centroid (2,) and its Jacobian (2, 5)."""
        pts, jac = self._project(self._tip_points, q)
        return polygon_centroid(pts[1:]), pose_jacobian(jac[:2])

    def project(self, q: np.ndarray, jacobian: bool = True):
        """Model pixels of the 13 tracked points (tip = face centroid), shape (13, 2).

        Returns
        -------
        uv : ndarray, shape (13, 2)
        jac : ndarray, shape (13, 2, 5) or None
            d uv / d (dz, a, b, sx, sy). The tip row is the Jacobian of the
            projected disc centre, which differs from the centroid's by O(1e-3).
        rim_uv : ndarray, shape (N_RIM, 2)
            Projected rim of the end face.
        """
        pts, jac = self._project(self.object_points, q)
        uv = np.empty((TIP + 1, 2))
        uv[:TIP] = pts[:TIP]
        rim = pts[TIP + 1 :]
        uv[TIP] = polygon_centroid(rim)
        if not jacobian:
            return uv, None, rim
        j = jac[: 2 * (TIP + 1)].reshape(TIP + 1, 2, -1)
        return uv, pose_jacobian(j), rim

    @cached_property
    def _points_by_plate(self) -> np.ndarray:
        """d object_points / d the [plate] dimensions, shape (n, 3, len(_PLATE_KEYS));
        z_i moves no plate point (it enters the motion)."""
        plate, h = self.sensor.plate, _PLATE_STEP_MM
        cols = []
        for key in _PLATE_KEYS:
            v = getattr(plate, key)
            up = tracked_object_points(dataclasses.replace(plate, **{key: v + h}))
            down = tracked_object_points(dataclasses.replace(plate, **{key: v - h}))
            cols.append((up - down) / (2 * h))
        return np.stack(cols, axis=-1)

    def jacobians(self, q: np.ndarray) -> ModelJacobians:
        """Model pixels of the tracked points at q with exact d / d q and d / d geometry.

        The corners' rows are OpenCV's analytic Jacobian, chained through the
        motion for the plate dimensions; the tip's row is the face centroid's,
        chained through its rim's rows (:func:`polygon_centroid_jacobian`).
        Not for the hot path: :meth:`project` is the pose fit's.
        """
        many = self.jacobians_many(np.asarray(q, dtype=float)[None])
        return ModelJacobians(*(getattr(many, f.name)[0] for f in dataclasses.fields(many)))

    def jacobians_many(self, q: np.ndarray) -> ModelJacobians:
        """:meth:`jacobians` at each of the poses q, shape (F, 5): every array with a
        leading axis of F. One projection per pose; the chain rule over all at once."""
        q = np.asarray(q, dtype=float).reshape(-1, 5)
        n_f, n_pts = len(q), len(self.object_points)
        pts, jac = np.empty((n_f, n_pts, 2)), np.empty((n_f, n_pts, 2, 15))
        rot = np.empty((n_f, 3, 3))
        for f, qf in enumerate(q):
            rvec, tvec = rigid_motion(qf, self.z_i_mm)
            pts[f], jac_f = project_rigid(self.object_points, rvec, tvec, self.camera)
            jac[f] = jac_f.reshape(n_pts, 2, -1)
            rot[f] = cv2.Rodrigues(rvec)[0]
        d_cam = jac[..., JAC_TVEC]  # d uv / d the point in the camera frame
        d_point = d_cam @ rot[:, None]  # ... in the plate frame
        n_pose, n_cam = 5, len(INTRINSIC_NAMES)
        d_all = np.empty((n_f, n_pts, 2, n_pose + len(GEOMETRY_NAMES)))  # pose, then geometry
        d_all[..., :n_pose] = pose_jacobian(jac)
        d_all[..., n_pose : n_pose + n_cam] = jac[..., JAC_INTRINSICS]
        np.matmul(d_point, self._points_by_plate, out=d_all[..., n_pose + n_cam :])
        d_all[..., n_pose + n_cam + _PLATE_KEYS.index("z_i_mm")] += d_cam[..., 2]
        uv, d_uv = np.empty((n_f, TIP + 1, 2)), np.empty((n_f, TIP + 1, 2, d_all.shape[-1]))
        uv[:, :TIP], d_uv[:, :TIP] = pts[:, :TIP], d_all[:, :TIP]
        rim, d_rim = pts[:, TIP + 1 :], d_all[:, TIP + 1 :]
        for f in range(n_f):  # the compiled kernels take one polygon
            uv[f, TIP] = polygon_centroid(rim[f])
            d_uv[f, TIP] = polygon_centroid_jacobian(rim[f], d_rim[f])
        return ModelJacobians(uv, d_uv[..., :n_pose], d_uv[..., n_pose:], d_point[:, :TIP])


def build_tolerances(sensor: Sensor) -> np.ndarray:
    """Each of ``GEOMETRY_NAMES``'s build tolerance (:data:`BUILD_TOLERANCE`) for this
    sensor, in its units, shape (len(GEOMETRY_NAMES),)."""
    g = geometry_vector(sensor)
    return np.array([BUILD_TOLERANCE[name] * (g[i] if name in RELATIVE_TOLERANCE else 1.0)
                     for i, name in enumerate(GEOMETRY_NAMES)])  # fmt: skip


def geometry_vector(sensor: Sensor) -> np.ndarray:
    """The sensor's values of ``GEOMETRY_NAMES``, shape (len(GEOMETRY_NAMES),)."""
    cam, plate = sensor.camera, sensor.plate
    intrinsics = [cam.fx_px, cam.fy_px, cam.cx_px, cam.cy_px, *cam.distortion]
    return np.array(intrinsics + [getattr(plate, k) for k in _PLATE_KEYS], dtype=float)


def with_geometry(sensor: Sensor, values: np.ndarray) -> Sensor:
    """A copy of the sensor with the values of ``GEOMETRY_NAMES`` set (validated)."""
    values = [float(v) for v in values]
    n = len(INTRINSIC_NAMES)
    fx, fy, cx, cy, *dist = values[:n]
    camera = {"fx_px": fx, "fy_px": fy, "cx_px": cx, "cy_px": cy, "distortion": dist}
    return sensor.replace(camera=camera, plate=dict(zip(_PLATE_KEYS, values[n:], strict=True)))
