"""Plate pose from tracked image points, through the exact camera model.

The pose vector is q = (dz_mm, a_rad, b_rad, sx_mm, sy_mm) with
a = phi cos(theta) and b = phi sin(theta): the tilt as a 2-vector, smooth
through phi = 0 where theta has no meaning. The rotation vector of the plate
is then (b, -a, 0), the Rodrigues form of :func:`camwhisker.plate.rotation_cam_from_plate`.

Tracked points (``POINT_NAMES``): the square's 4 corners, the 8 outer corners
of the cross's arm ends, and the magnifier tip. The tip's image is the end
face's centroid; its model value is the area centroid of the projected rim
circle (the projection of a disc's centre is not its image's centroid).

The fit is Gauss-Newton on the pixel residuals
``measured - rest_offset - model(q)``, with OpenCV's analytic projection
Jacobian (lens distortion included). The rest offsets are the residuals at
the rest frame (q = 0), so a constant detector or model bias cancels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from camwhisker.plate import Pose, cross_arm_edges, cross_outline, rod_ends, square_corners
from camwhisker.sensor import Sensor

__all__ = [
    "POINT_NAMES",
    "N_SQUARE",
    "N_CROSS",
    "TIP",
    "PlateModel",
    "PoseFit",
    "fit_pose",
    "refit_pose",
    "q_to_pose",
    "polygon_centroid",
    "polygon_area",
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

#: Points on each of the rod's end rims for its outline.
ROD_RIM = 24
#: cv2.projectPoints' Jacobian columns (rvec x, y, z, tvec x, y, z, ...) that make
#: d / d (dz, a, b, sx, sy), with rvec = (b, -a, 0) and tvec = (sx, sy, z_i - dz).
_JAC_COLUMNS = np.array([5, 1, 0, 3, 4])
_JAC_SIGNS = np.array([-1.0, -1.0, 1.0, 1.0, 1.0])

#: Gauss-Newton stops when the largest step is below this (mm or rad). The next step
#: would be far smaller: on the live clip's fits, after a step below 1e-3 the next was
#: at most 0.003 of it, so < 3e-8 rad (2e-6 deg) is left unsolved, far below the
#: noise. 1e-6 cost a projection more in most fits (2.6 against 2.2 a fit).
GN_STEP_TOL = 1e-5
GN_MAX_ITER = 12
#: :func:`refit_pose` takes one step up to this (mm or rad); a larger one is
#: iterated. On the live clip's 103 refits (steps up to 0.023 mm and 3.7e-3 rad)
#: one step left <= 7e-6 rad (4e-4 deg) of tilt and <= 1.2e-4 mm of dz and shift
#: unsolved: 3% and 2% of the front end's phi and dz errors, added in quadrature.
REFIT_STEP_MAX = 0.03


def _pose_jacobian(jac: np.ndarray) -> np.ndarray:
    """Rows of cv2.projectPoints' Jacobian as d / d (dz, a, b, sx, sy), shape (..., 5)."""
    return jac[..., _JAC_COLUMNS] * _JAC_SIGNS


def q_to_pose(q: np.ndarray) -> Pose:
    """Pose from q = (dz_mm, a_rad, b_rad[, sx_mm, sy_mm])."""
    sx, sy = (q[3], q[4]) if len(q) > 3 else (0.0, 0.0)
    return Pose(float(q[0]), math.hypot(q[1], q[2]), math.atan2(q[2], q[1]), float(sx), float(sy))


@njit(cache=True, nogil=True, error_model="numpy")
def polygon_centroid(uv: np.ndarray) -> np.ndarray:
    """Area centroid of a closed polygon, shape (N, 2) -> (2,) (shoelace formula)."""
    n = uv.shape[0]
    area = cx = cy = 0.0
    for i in range(n):
        j = (i + 1) % n
        cross = uv[i, 0] * uv[j, 1] - uv[j, 0] * uv[i, 1]
        area += cross
        cx += cross * (uv[i, 0] + uv[j, 0])
        cy += cross * (uv[i, 1] + uv[j, 1])
    out = np.empty(2)
    out[0], out[1] = cx / (3.0 * area), cy / (3.0 * area)
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def polygon_area(uv: np.ndarray) -> float:
    """Unsigned area of a closed polygon, shape (N, 2) (shoelace formula)."""
    n = uv.shape[0]
    twice = 0.0
    for i in range(n):
        j = (i + 1) % n
        twice += uv[i, 0] * uv[j, 1] - uv[j, 0] * uv[i, 1]
    return abs(twice) / 2.0


class PlateModel:
    """The forward model of :mod:`camwhisker.plate` for the tracked points, with Jacobian.

    Parameters
    ----------
    sensor : Sensor
    """

    def __init__(self, sensor: Sensor):
        self.sensor = sensor
        plate, cam = sensor.plate, sensor.camera
        rho = plate.rod_diameter_mm / 2
        ang = np.linspace(0.0, 2 * np.pi, N_RIM, endpoint=False)
        rim = np.column_stack([rho * np.cos(ang), rho * np.sin(ang), np.full(N_RIM, -plate.h_r_mm)])
        #: Plate-frame points: 12 tracked corners, the tip centre, the rim.
        self.object_points = np.ascontiguousarray(
            np.concatenate(
                [square_corners(plate), cross_arm_edges(plate).reshape(-1, 3),
                 rod_ends(plate)[1:], rim]
            )
        )  # fmt: skip
        self._tip_points = self.object_points[TIP:]  # the face's centre, then its rim
        self._corner_points = np.ascontiguousarray(self.object_points[:TIP])
        # Edge directions at each tracked corner, in the plate frame: (12, 2, 3).
        sq = square_corners(plate)
        sq_dirs = np.stack([np.roll(sq, 1, axis=0) - sq, np.roll(sq, -1, axis=0) - sq], axis=1)
        arm = cross_arm_edges(plate)  # (4, 2, 3): the two end corners of each arm
        inward = np.array(
            [[-1.0, 0, 0], [0, -1.0, 0], [1.0, 0, 0], [0, 1.0, 0]]
        )  # arms +x +y -x -y
        cr_dirs = [[end[1 - i] - end[i], inward[j]] for j, end in enumerate(arm) for i in (0, 1)]
        self._edge_dirs_plate = np.concatenate([sq_dirs, np.array(cr_dirs)], axis=0)
        #: The corners and points step_mm along their edges, by step_mm (see edge_directions).
        self._edge_points: dict[float, np.ndarray] = {}
        # Plate-frame outlines (see outlines()): the end face's rim, the rod's two
        # end rims, the cross.
        ang = np.linspace(0.0, 2 * np.pi, ROD_RIM, endpoint=False)
        ring = np.column_stack([rho * np.cos(ang), rho * np.sin(ang)])
        self._outline_points = np.ascontiguousarray(
            np.concatenate([
                rim,
                np.column_stack([ring, np.full(ROD_RIM, -plate.cross_offset_mm)]),
                np.column_stack([ring, np.full(ROD_RIM, -plate.h_r_mm)]),
                cross_outline(plate),
            ])
        )  # fmt: skip
        self.K = cam.matrix
        self.dist = cam.dist_coeffs
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
        rod_end = N_RIM + 2 * ROD_RIM
        return uv[:N_RIM], uv[N_RIM:rod_end], uv[rod_end:]

    def _project(self, pts: np.ndarray, q: np.ndarray):
        """cv2.projectPoints of plate-frame points (n, 3) at pose q: pixels (n, 2) and
        OpenCV's Jacobian (2 n, 15)."""
        q = np.asarray(q, dtype=float)
        sx, sy = (q[3], q[4]) if len(q) > 3 else (0.0, 0.0)
        rvec = np.array([q[2], -q[1], 0.0])
        tvec = np.array([sx, sy, self.z_i_mm - q[0]])
        uv, jac = cv2.projectPoints(pts, rvec, tvec, self.K, self.dist)
        return uv.reshape(-1, 2), jac

    def corners(self, q: np.ndarray) -> np.ndarray:
        """The 12 tracked corners' rows of :meth:`project` alone, shape (12, 2), from
        one projection of those points."""
        return self._project(self._corner_points, q)[0]

    def tip(self, q: np.ndarray):
        """The tip's row of :meth:`project` alone, from one smaller projection: the
        face centroid (2,) and its Jacobian (2, 5)."""
        pts, jac = self._project(self._tip_points, q)
        return polygon_centroid(pts[1:]), _pose_jacobian(jac[:2])

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
        return uv, _pose_jacobian(j), rim


@dataclass(frozen=True)
class PoseFit:
    """Result of :func:`fit_pose`.

    q : ndarray, shape (5,)
        (dz_mm, a_rad, b_rad, sx_mm, sy_mm); the shift is 0 when not fitted.
    cov : ndarray, shape (5, 5)
        Covariance of q from the residual scatter (zeros for unfitted terms).
    rms_px : float
        Root mean square residual over the used coordinates.
    n_points : int
    converged : bool
    used : ndarray of bool, shape (13,)
        Points the final fit used (after outlier rejection).
    model_uv : ndarray, shape (13, 2)
        The model's pixels of the points at q (without the rest offsets).
    jac : ndarray, shape (13, 2, 5)
        d model_uv / d q, what :func:`refit_pose` steps with: at q, or after
        such a step at the pose it stepped from (and model_uv moved along it).
    """

    q: np.ndarray
    cov: np.ndarray
    rms_px: float
    n_points: int
    converged: bool
    used: np.ndarray | None = None
    model_uv: np.ndarray | None = None
    jac: np.ndarray | None = None

    @property
    def pose(self) -> Pose:
        return q_to_pose(self.q)

    @property
    def phi_sigma_rad(self) -> float:
        """Standard error of phi, from the covariance of (a, b) along the tilt."""
        a, b = self.q[1], self.q[2]
        phi = math.hypot(a, b)
        c = self.cov[1:3, 1:3]
        if phi == 0.0:
            return math.sqrt(max(np.trace(c) / 2, 0.0))
        e = np.array([a, b]) / phi
        return math.sqrt(max(e @ c @ e, 0.0))


#: Outlier rejection: a point whose residual exceeds both OUTLIER_MIN_PX and
#: OUTLIER_FACTOR times the median residual is dropped and the pose refitted, at
#: most MAX_REJECTED times. Good corners leave ~0.1 px (nominal) to ~0.3 px (hard).
OUTLIER_MIN_PX = 0.6
OUTLIER_FACTOR = 4.0
MAX_REJECTED = 3


def fit_pose(
    model: PlateModel,
    measured_uv: np.ndarray,
    offsets_uv: np.ndarray,
    q0: np.ndarray,
    weights: np.ndarray | None = None,
    fit_shift: bool = True,
    reject_outliers: bool = True,
) -> PoseFit:
    """Least-squares plate pose from tracked points, with outlier rejection.

    See :func:`_fit_once` for the parameters; ``reject_outliers`` drops the
    worst point while it is far off (OUTLIER_MIN_PX, OUTLIER_FACTOR), up to
    MAX_REJECTED points, never the tip.
    """
    w = np.ones(TIP + 1) if weights is None else np.asarray(weights, float).copy()
    fit = _fit_once(model, measured_uv, offsets_uv, q0, w, fit_shift)
    if not reject_outliers:
        return fit
    for _ in range(MAX_REJECTED):
        if not fit.converged:
            return fit
        res = np.hypot(*(np.asarray(measured_uv, float) - offsets_uv - fit.model_uv).T)
        res[~fit.used] = np.nan
        res[TIP] = np.nan
        if not np.isfinite(res).any():
            return fit
        k = int(np.argmax(np.where(np.isfinite(res), res, -np.inf)))
        if not (res[k] > OUTLIER_MIN_PX and res[k] > OUTLIER_FACTOR * np.nanmedian(res)):
            return fit
        w[k] = 0.0
        fit = _fit_once(model, measured_uv, offsets_uv, fit.q, w, fit_shift)
    return fit


def _fit_once(
    model: PlateModel,
    measured_uv: np.ndarray,
    offsets_uv: np.ndarray,
    q0: np.ndarray,
    weights: np.ndarray | None = None,
    fit_shift: bool = True,
) -> PoseFit:
    """Least-squares plate pose from tracked points (Gauss-Newton).

    Parameters
    ----------
    model : PlateModel
    measured_uv : ndarray, shape (13, 2)
        Measured pixels of the points of ``POINT_NAMES``; NaN where not measured.
    offsets_uv : ndarray, shape (13, 2)
        Rest offsets (measured - model at the rest pose).
    q0 : ndarray, shape (5,)
        Starting pose (usually the previous frame's).
    weights : ndarray, shape (13,), optional
        Relative weight of each point (1 / variance); default all ones.
    fit_shift : bool
        Fit the lateral shift (sx, sy) too; else it is held at 0.

    Returns
    -------
    PoseFit
        ``converged`` is False when fewer points than needed are usable or the
        normal equations are singular.
    """
    n_par = 5 if fit_shift else 3
    target, use, sw = _observations(measured_uv, offsets_uv, weights)
    q = np.zeros(5)
    q[:n_par] = np.asarray(q0, float)[:n_par]
    if 2 * int(use.sum()) < n_par + 1:
        return PoseFit(q, np.zeros((5, 5)), math.nan, int(use.sum()), False, use)
    converged = False
    for _ in range(GN_MAX_ITER):
        uv, jac, _ = model.project(q)
        step = _gn_step(q, uv, jac, target, sw, n_par)
        if step is None:
            break
        if np.abs(step).max() < GN_STEP_TOL:
            converged = True
            break
    if converged:
        # The last step is below GN_STEP_TOL: the model at q is the last projection
        # moved along its Jacobian, to 1e-6 px (the tip row, whose Jacobian is the
        # disc centre's; 200 random poses), and the Jacobian at q differs from the
        # last one by < 1e-6 relative. q is unchanged; one projection is saved.
        return _pose_fit(q, uv + jac @ step, jac, target, use, sw, n_par, True)
    uv, jac, _ = model.project(q)
    return _pose_fit(q, uv, jac, target, use, sw, n_par, False)


def refit_pose(
    model: PlateModel,
    fit: PoseFit,
    measured_uv: np.ndarray,
    offsets_uv: np.ndarray,
    weights: np.ndarray,
    fit_shift: bool = True,
    add: int | None = None,
) -> PoseFit:
    """``fit`` again after a measurement moved by a little (the tip measured anew).

    One Gauss-Newton step from ``fit.q`` with the fit's own model pixels and
    Jacobian, so no projection; the points ``fit`` left out stay out, except
    point ``add`` (one measured only now, such as the tip after the corners'
    fit). A step above REFIT_STEP_MAX is iterated by Gauss-Newton from
    ``fit.q`` instead; a smaller one leaves a little unsolved (see REFIT_STEP_MAX).
    """
    if not fit.converged or fit.jac is None:
        raise ValueError("refit_pose needs a converged fit with its Jacobian")
    n_par = 5 if fit_shift else 3
    used = fit.used.copy()
    if add is not None:
        used[add] = True
    weights = np.asarray(weights, float) * used
    target, use, sw = _observations(measured_uv, offsets_uv, weights)
    if 2 * int(use.sum()) < n_par + 1:
        return PoseFit(fit.q.copy(), np.zeros((5, 5)), math.nan, int(use.sum()), False, use)
    q = fit.q.copy()
    step = _gn_step(q, fit.model_uv, fit.jac, target, sw, n_par)
    if step is None or np.abs(step).max() > REFIT_STEP_MAX:
        return _fit_once(model, measured_uv, offsets_uv, fit.q, weights, fit_shift)
    return _pose_fit(q, fit.model_uv + fit.jac @ step, fit.jac, target, use, sw, n_par, True)


def _observations(measured_uv, offsets_uv, weights):
    """Targets (13, 2), the points used (13,) and their sqrt weights (13, 1).

    An unused point gets weight 0 and target 0, so its rows of the weighted
    problem are exact zeros: the normal equations are those of the used points,
    without selecting them anew at every step."""
    w = np.ones(TIP + 1) if weights is None else np.asarray(weights, float)
    return _observations_kernel(np.asarray(measured_uv, float), np.asarray(offsets_uv, float), w)


@njit(cache=True, nogil=True, error_model="numpy")
def _observations_kernel(measured, offsets, weights):
    n = measured.shape[0]
    target = np.zeros((n, 2))
    use = np.zeros(n, np.bool_)
    sw = np.zeros((n, 1))
    for k in range(n):
        u, v = measured[k, 0] - offsets[k, 0], measured[k, 1] - offsets[k, 1]
        if np.isfinite(u) and np.isfinite(v) and weights[k] > 0:
            target[k, 0], target[k, 1] = u, v
            use[k] = True
            sw[k, 0] = np.sqrt(weights[k])
    return target, use, sw


@njit(cache=True, nogil=True, error_model="numpy")
def _normal_equations(uv, jac, target, sw, n_par):
    """J^T J (n_par, n_par), J^T r (n_par, 1) and r^T r of the weighted problem:
    residuals r = sw (target - uv), Jacobian J = sw jac[..., :n_par]; unused
    points have sw = 0 and add nothing."""
    jtj = np.zeros((n_par, n_par))
    jtr = np.zeros((n_par, 1))
    rr = 0.0
    for k in range(uv.shape[0]):
        w = sw[k, 0]
        if w == 0.0:
            continue
        for c in range(2):
            r = w * (target[k, c] - uv[k, c])
            rr += r * r
            for i in range(n_par):
                ji = w * jac[k, c, i]
                jtr[i, 0] += ji * r
                for j in range(i + 1):
                    jtj[i, j] += ji * w * jac[k, c, j]
    for i in range(n_par):
        for j in range(i):
            jtj[j, i] = jtj[i, j]
    return jtj, jtr, rr


def _gn_step(q, uv, jac, target, sw, n_par):
    """One Gauss-Newton step, taken on q in place: the step (5,), or None if singular."""
    jtj, jtr, _ = _normal_equations(uv, jac, target, sw, n_par)
    # The normal equations (symmetric, positive definite unless singular) by
    # OpenCV's Cholesky solver: ~10x less overhead than np.linalg.solve at 5 x 5.
    solved, step = cv2.solve(jtj, jtr, flags=cv2.DECOMP_CHOLESKY)
    if not solved:
        return None
    full = np.zeros(5)
    full[:n_par] = step.ravel()
    q += full
    return full


def _pose_fit(q, uv, jac, target, use, sw, n_par, converged) -> PoseFit:
    """The fit at q, given the model pixels and Jacobian there."""
    jtj, _, rr = _normal_equations(uv, jac, target, sw, n_par)
    n_obs = 2 * int(use.sum())
    s2 = rr / max(n_obs - n_par, 1)
    cov = np.zeros((5, 5))
    invertible, inverse = cv2.invert(jtj, flags=cv2.DECOMP_CHOLESKY)
    if invertible:
        cov[:n_par, :n_par] = s2 * inverse
    else:
        converged = False
    return PoseFit(q, cov, math.sqrt(rr / n_obs), int(use.sum()), converged, use, uv, jac)
