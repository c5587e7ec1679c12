"""Pinhole camera with OpenCV lens distortion: project and unproject, vectorised.

Conventions (docs/sensor.md section 2): the camera frame has x to the right of the
image (+u), y down (+v) and z along the optical axis, away from the camera.
Pixel (u, v) = (column, row), with (0, 0) the centre of the top-left pixel.

Projection of a point (X, Y, Z) in the camera frame::

    x = X / Z,  y = Y / Z,  r^2 = x^2 + y^2
    x_d = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2)
    y_d = y (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 y^2) + 2 p2 x y
    u = fx x_d + cx,  v = fy y_d + cy

Both directions are delegated to OpenCV (``cv2.projectPoints`` and the
iterative ``cv2.undistortPoints``). :func:`project_rigid` is the one call of
``cv2.projectPoints``: it moves object points by a rigid motion (rvec, tvec)
into the camera frame, projects them, and returns OpenCV's analytic Jacobian
with respect to the motion and the intrinsics (columns ``JAC_*``).

Degenerate cases
----------------
- A point with Z <= 0 (on or behind the camera centre) has no image: its
  projection is NaN.
- Under strong distortion the map from (x, y) to (x_d, y_d) can fold over, so
  a pixel may have no ray, and the fixed-point iteration of the inverse may
  stop short. :func:`unproject` checks every result by projecting it again and
  returns NaN where the round trip misses the input by more than
  ``ROUND_TRIP_TOL_PX``.
- Non-finite input gives NaN output.
"""

from __future__ import annotations

import cv2
import numpy as np

from camwhisker.sensor.file import CameraConfig

__all__ = [
    "project",
    "project_rigid",
    "unproject",
    "pixel_rays",
    "ROUND_TRIP_TOL_PX",
    "INTRINSIC_NAMES",
    "JAC_RVEC",
    "JAC_TVEC",
    "JAC_INTRINSICS",
]

#: A ray is accepted only if it projects back within this distance of its pixel.
#: The iteration reaches ~1e-13 px where it converges; 1e-6 px leaves room for
#: rounding and rejects the fold-over region, where errors are pixels.
ROUND_TRIP_TOL_PX = 1e-6

# Enough iterations to converge to machine precision for |k1| up to ~0.5 over
# the frame; the round-trip check catches the rest.
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
_ZERO3 = np.zeros(3)

#: The intrinsics in the order of :func:`project_rigid`'s Jacobian columns
#: ``JAC_INTRINSICS``; k1 ... k3 are ``CameraConfig.distortion`` in its order.
INTRINSIC_NAMES = ("fx_px", "fy_px", "cx_px", "cy_px", "k1", "k2", "p1", "p2", "k3")
#: Columns of :func:`project_rigid`'s Jacobian (OpenCV's order): d / d rvec,
#: d / d tvec (the same as d / d the point in the camera frame), d / d intrinsics.
JAC_RVEC = slice(0, 3)
JAC_TVEC = slice(3, 6)
JAC_INTRINSICS = slice(6, 6 + len(INTRINSIC_NAMES))


def project_rigid(
    points: np.ndarray, rvec: np.ndarray, tvec: np.ndarray, camera: CameraConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Project object points moved by a rigid motion, with the Jacobian.

    The point p goes to R(rvec) p + tvec in the camera frame (R by Rodrigues'
    formula), then to pixels as in the module notes. No checks: every point
    must be finite and lie in front of the camera (see :func:`project`).

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        Points in the object frame, float64.
    rvec, tvec : ndarray, shape (3,)
        Rotation vector (rad) and translation of the motion.
    camera : CameraConfig

    Returns
    -------
    uv : ndarray, shape (N, 2)
    jac : ndarray, shape (2 N, 15)
        d (u0, v0, u1, v1, ...) / d (rvec, tvec, fx, fy, cx, cy, k1, k2, p1,
        p2, k3): see ``JAC_RVEC``, ``JAC_TVEC`` and ``JAC_INTRINSICS``.
    """
    uv, jac = cv2.projectPoints(points, rvec, tvec, camera.matrix, camera.dist_coeffs)
    return uv.reshape(-1, 2), jac


def project(points_in_camera: np.ndarray, camera: CameraConfig) -> np.ndarray:
    """Project 3D points in the camera frame to pixels.

    Parameters
    ----------
    points_in_camera : ndarray, shape (..., 3)
        Points in millimetres (any length unit works).
    camera : CameraConfig

    Returns
    -------
    uv : ndarray, shape (..., 2)
        Pixel coordinates; NaN where Z <= 0 or the input is not finite.
    """
    pts = np.asarray(points_in_camera, dtype=float)
    shape = pts.shape[:-1]
    flat = pts.reshape(-1, 3)
    valid = np.isfinite(flat).all(axis=1) & (flat[:, 2] > 0)
    uv = np.full((flat.shape[0], 2), np.nan)
    if valid.any():
        uv[valid] = project_rigid(flat[valid], _ZERO3, _ZERO3, camera)[0]
    return uv.reshape(*shape, 2)


def unproject(uv: np.ndarray, camera: CameraConfig) -> np.ndarray:
    """Normalised ray (x, y) = (X/Z, Y/Z) of each pixel; the inverse of :func:`project`.

    Parameters
    ----------
    uv : ndarray, shape (..., 2)
        Pixel coordinates.
    camera : CameraConfig

    Returns
    -------
    xy : ndarray, shape (..., 2)
        The point (x, y, 1) lies on the pixel's ray. NaN where the pixel has
        no ray under the distortion model (see module notes) or is not finite.
    """
    pix = np.asarray(uv, dtype=float)
    shape = pix.shape[:-1]
    flat = pix.reshape(-1, 2)
    valid = np.isfinite(flat).all(axis=1)
    xy = np.full(flat.shape, np.nan)
    if not valid.any():
        return xy.reshape(*shape, 2)
    if not camera.has_distortion:
        xy[valid, 0] = (flat[valid, 0] - camera.cx_px) / camera.fx_px
        xy[valid, 1] = (flat[valid, 1] - camera.cy_px) / camera.fy_px
        return xy.reshape(*shape, 2)
    src = np.ascontiguousarray(flat[valid]).reshape(-1, 1, 2)
    eye = np.eye(3)
    rays = cv2.undistortPoints(
        src, camera.matrix, camera.dist_coeffs, None, eye, eye, _UNDISTORT_CRITERIA
    ).reshape(-1, 2)
    back = project(np.column_stack([rays, np.ones(len(rays))]), camera)
    miss = np.hypot(*(back - flat[valid]).T)
    rays[~(miss <= ROUND_TRIP_TOL_PX)] = np.nan
    xy[valid] = rays
    return xy.reshape(*shape, 2)


def pixel_rays(camera: CameraConfig) -> np.ndarray:
    """Normalised ray of every pixel centre, shape (height, width, 2)."""
    v, u = np.mgrid[0 : camera.height_px, 0 : camera.width_px].astype(float)
    return unproject(np.stack([u, v], axis=-1), camera)
