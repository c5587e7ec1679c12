"""Plate pose from tracked image points, through the forward model.

The pose vector is q = (dz_mm, a_rad, b_rad, sx_mm, sy_mm) of
:mod:`camwhisker.sensor.plate`; the model pixels of the tracked points
(``camwhisker.sensor.model.POINT_NAMES``) and their Jacobian come from
:class:`camwhisker.sensor.model.PlateModel`.

The fit is Gauss-Newton on the pixel residuals
``measured - offset - model(q)``, with OpenCV's analytic projection
Jacobian (lens distortion included). The offsets are the residuals at the
rest frame (q = 0), so a detector or model bias cancels; the tracker moves a
corner's offset with its neighbourhood's affine map at q (a blurred corner's
detected point sits inside it, and turns with it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from camwhisker.kernels import pose as kernels
from camwhisker.sensor.model import TIP, PlateModel
from camwhisker.sensor.plate import Pose, q_to_pose

__all__ = [
    "PoseFit",
    "fit_pose",
    "refit_pose",
]

#: Gauss-Newton stops when the largest step is below this (mm or rad): convergence is
#: quadratic, so what the next step would add lies far below the noise.
GN_STEP_TOL = 1e-5
GN_MAX_ITER = 12
#: :func:`refit_pose` takes one step up to this (mm or rad); a larger one is
#: iterated: below it, what one step leaves unsolved is a few % of the front end's error.
REFIT_STEP_MAX = 0.03


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
#: most MAX_REJECTED times. OUTLIER_MIN_PX lies above a good corner's residual.
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
        # After a step below GN_STEP_TOL the last projection moved along its Jacobian
        # is the model at q to ~1e-6 px: one projection saved, q unchanged.
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
    return kernels.observations_kernel(np.asarray(measured_uv, float),
                                       np.asarray(offsets_uv, float), w)  # fmt: skip


def _gn_step(q, uv, jac, target, sw, n_par):
    """One Gauss-Newton step, taken on q in place: the step (5,), or None if singular."""
    jtj, jtr, _ = kernels.normal_equations(uv, jac, target, sw, n_par)
    # Cholesky (the normal equations are symmetric positive definite unless singular)
    # by OpenCV: far less call overhead than np.linalg.solve at 5 x 5.
    solved, step = cv2.solve(jtj, jtr, flags=cv2.DECOMP_CHOLESKY)
    if not solved:
        return None
    full = np.zeros(5)
    full[:n_par] = step.ravel()
    q += full
    return full


def _pose_fit(q, uv, jac, target, use, sw, n_par, converged) -> PoseFit:
    """The fit at q, given the model pixels and Jacobian there."""
    jtj, _, rr = kernels.normal_equations(uv, jac, target, sw, n_par)
    n_obs = 2 * int(use.sum())
    s2 = rr / max(n_obs - n_par, 1)
    cov = np.zeros((5, 5))
    invertible, inverse = cv2.invert(jtj, flags=cv2.DECOMP_CHOLESKY)
    if invertible:
        cov[:n_par, :n_par] = s2 * inverse
    else:
        converged = False
    return PoseFit(q, cov, math.sqrt(rr / n_obs), int(use.sum()), converged, use, uv, jac)
