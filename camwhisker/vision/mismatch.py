"""The mismatch check: does the sensor file describe the sensor in the video?

At the rest reference the detected points should lie where the sensor file's
model puts them at pose zero; their offsets (``RestReference.offsets``) are
what the file gets wrong plus detection noise and bias. :func:`check_mismatch`
compares them with what noise explains, estimates the geometry deviation that
explains them (regularised least squares through the model's geometry
Jacobian, each parameter's prior scale the typical deviation of a hand build,
SENSOR.md section 8), predicts what that deviation does to phi at
``CHECK_PHI_DEG`` (the nominal model fitted, linearised, to the deviated
model's points) and warns when it exceeds ``PHI_ERROR_WARN_DEG``.

What the rest frame cannot see is not checked: the tip lies near the optical
axis at rest, so the rod length h_r barely moves any rest point; a sweep
(``camwhisker calibrate-sensor``) finds it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from camwhisker.sensor.model import (
    GEOMETRY_NAMES,
    N_SQUARE,
    RELATIVE_TOLERANCE,
    TIP,
    PlateModel,
    build_tolerances,
)

__all__ = ["MismatchCheck", "check_mismatch", "prior_scales", "phi_response", "phi_error_deg",
           "dz_gain_response", "edge_corners", "edge_crossings", "PHI_ERROR_WARN_DEG"]

#: Tilt at which the deviation's effect on phi is judged (deg): a working tilt.
CHECK_PHI_DEG = 20.0
#: dz (mm) at which the dz gain is checked: mid-range of the paper's test 2 (0.1-1.0 mm).
CHECK_DZ_MM = 0.5
#: Tilt directions it is judged at (deg); the largest effect counts.
CHECK_THETA_DEG = (0.0, 45.0, 90.0, 135.0, 180.0, 225.0, 270.0, 315.0)
#: Warn when the predicted phi error at CHECK_PHI_DEG exceeds this (deg).
PHI_ERROR_WARN_DEG = 0.05
#: ... and the offsets' normalised chi-square exceeds this: more than noise explains
#: (its 99.9th percentile for 26 residuals is ~2.1).
CHI2_WARN = 2.1
#: Largest squared normalised offset a point adds to the chi-square (3 sigma).
CHI2_CLIP = 9.0
#: Spread of the corners' rest offsets that detection bias alone gives on renders
#: with the sensor file's own geometry (px, per coordinate; ~0.2 at the nominal
#: webcam's blur, ~0.65 at 2.6 px blur and 5 DN noise): the floor of each point's noise.
BIAS_PX = 0.5
#: ... growing with the image's blur as measured at rest (Gaussian sigma, px), this
#: much per px: a blurred corner's detected point and its edges' lines move more.
BIAS_PER_BLUR = 0.25
#: Per-point scatter assumed where only one rest frame gives none (px, per coordinate).
SCATTER_ONE_FRAME_PX = 0.05
#: A parameter is a suspect when its estimated deviation is at least this many
#: prior scales; at most MAX_SUSPECTS are named, largest first.
SUSPECT_SCALES = 0.25
MAX_SUSPECTS = 3
#: Edge profiles start and end this far from the detected corner (px: clear of the
#: corner's blur and of the springs' ends) and extend PROFILE_HALF_PX each side of
#: the edge, sampled every PROFILE_STEP_PX; a profile needs a share step of
#: EDGE_MIN_STEP, a line EDGE_MIN_POINTS profiles.
EDGE_FROM_PX = 10
EDGE_TO_PX = 26
PROFILE_HALF_PX = 5.0
PROFILE_STEP_PX = 0.25
EDGE_MIN_STEP = 0.3
EDGE_MIN_POINTS = 6
#: Huber's threshold (normalised offsets) and its reweighting passes.
HUBER_K = 2.0
HUBER_PASSES = 4
#: Weight of the tip in the pose fit relative to a corner (the tracker's).
TIP_WEIGHT = 4.0


@dataclass(frozen=True)
class MismatchCheck:
    """The mismatch check at one rest reference (recorded in the sidecar).

    Attributes
    ----------
    residual_rms_px : float
        RMS of the rest points' offsets from the sensor file's prediction (px).
    noise_rms_px : float
        RMS of what noise and detection bias explain (px).
    chi2 : float
        The offsets' normalised chi-square against that noise (1: noise alone).
    phi_error_deg : float
        Predicted error of phi at CHECK_PHI_DEG from the estimated deviation (deg,
        the largest over the tilt directions).
    suspects : list of str
        The parameters most likely off, with their estimated deviation.
    warned : bool
    """

    residual_rms_px: float
    noise_rms_px: float
    chi2: float
    phi_error_deg: float
    suspects: list[str]
    warned: bool

    @property
    def message(self) -> str:
        """The warning's text ("" when it did not warn)."""
        if not self.warned:
            return ""
        return (
            f"the sensor file does not match this sensor: the rest points lie "
            f"{self.residual_rms_px:.2f} px (RMS) from its prediction, {self.chi2:.1f}x what "
            f"noise explains; phi at {CHECK_PHI_DEG:g} deg may be off by "
            f"~{self.phi_error_deg:.2f} deg. Most likely off: {', '.join(self.suspects)}. "
            f"Run `camwhisker calibrate-sensor` on a sweep of this sensor."
        )

    def as_dict(self) -> dict:
        return {
            "residual_rms_px": round(self.residual_rms_px, 4),
            "noise_rms_px": round(self.noise_rms_px, 4),
            "chi2": round(self.chi2, 3),
            "phi_error_deg": round(self.phi_error_deg, 4),
            "at_phi_deg": CHECK_PHI_DEG,
            "suspects": self.suspects,
            "warned": self.warned,
        }


def prior_scales(model: PlateModel) -> np.ndarray:
    """Prior scale of each of ``GEOMETRY_NAMES`` for this sensor: its build tolerance."""
    return build_tolerances(model.sensor)


def edge_corners(rest, model: PlateModel) -> tuple[np.ndarray, np.ndarray]:
    """The 12 corners at rest as the crossings of their two edges' lines, shape (12, 2),
    and each one's standard error from its edges' scatter (px), shape (12,): the
    :func:`edge_crossings` of the rest frame's share maps."""
    out, sd = edge_crossings(rest.red, rest.blue, rest.uv[:TIP] - rest.origin,
                             model.edge_directions(np.zeros(5)))  # fmt: skip
    return out + rest.origin, sd


def edge_crossings(red: np.ndarray, blue: np.ndarray, corners_uv: np.ndarray,
                   directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The 12 corners as the crossings of their two edges' lines in the share maps
    (map pixels), shape (12, 2), and each one's standard error (px), shape (12,).

    Each edge is found at half the colour share's step, on profiles across it
    EDGE_FROM_PX ... EDGE_TO_PX from the detected corner ``corners_uv`` along its
    ``directions`` (12, 2, 2): a straight edge's half level does not move with
    blur, while a blurred corner's detected point moves into its feature. NaN
    where an edge is not found.
    """
    unit = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
    out = np.full((TIP, 2), np.nan)
    sd = np.full(TIP, np.nan)
    for k in range(TIP):
        if not np.isfinite(corners_uv[k]).all():
            continue
        share = blue if k < N_SQUARE else red
        lines = [_edge_line(share, corners_uv[k], e, unit[k, 1 - j])
                 for j, e in enumerate(unit[k])]  # fmt: skip
        if all(line is not None for line in lines):
            out[k] = _crossing(*lines)
            sd[k] = math.hypot(lines[0][2], lines[1][2])
    return out, sd


def _edge_line(share: np.ndarray, corner: np.ndarray, along: np.ndarray, inward: np.ndarray):
    """The line of the edge leaving ``corner`` along ``along``: a point on it, its
    direction and the standard error of its offset (px); None if not found.

    ``inward`` is the corner's other edge: the side of the feature (high share)."""
    normal = np.array([-along[1], along[0]])
    if normal @ inward < 0:
        normal = -normal  # points into the feature
    t = np.arange(EDGE_FROM_PX, EDGE_TO_PX + 1, 1.0)
    s = np.arange(-PROFILE_HALF_PX, PROFILE_HALF_PX + PROFILE_STEP_PX / 2, PROFILE_STEP_PX)
    pts = corner + t[:, None, None] * along + s[None, :, None] * normal  # (nt, ns, 2)
    maps = pts.astype(np.float32)
    vals = cv2.remap(share, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)  # fmt: skip
    with np.errstate(all="ignore"):  # a profile off the map is NaN: skipped below
        lo, hi = np.nanmean(vals[:, :4], axis=1), np.nanmean(vals[:, -4:], axis=1)
        half = ((lo + hi) / 2)[:, None]
        above = vals >= half
        rises = ~above[:, :-1] & above[:, 1:]
        k = np.argmax(rises, axis=1)
        rows = np.arange(len(t))
        frac = (half[:, 0] - vals[rows, k]) / (vals[rows, k + 1] - vals[rows, k])
    # A profile counts with a clear step that it crosses once.
    keep = (hi - lo >= EDGE_MIN_STEP) & (rises.sum(axis=1) == 1)
    if np.count_nonzero(keep) < EDGE_MIN_POINTS:
        return None
    offset = s[k[keep]] + frac[keep] * PROFILE_STEP_PX
    found = corner + t[keep, None] * along + offset[:, None] * normal
    centre = found.mean(axis=0)
    _, sv, vt = np.linalg.svd(found - centre)
    # The crossings' scatter about the line; its offset is known to 1/sqrt(n) of that.
    sd = sv[1] / math.sqrt(len(found) * max(len(found) - 2, 1))
    return centre, vt[0], sd


def _crossing(line1, line2) -> np.ndarray:
    (p1, d1, _), (p2, d2, _) = line1, line2
    t = np.linalg.solve(np.column_stack([d1, -d2]), p2 - p1)
    return p1 + t[0] * d1


def _pose_fit_weights() -> np.ndarray:
    return np.repeat(np.where(np.arange(TIP + 1) == TIP, TIP_WEIGHT, 1.0), 2)


def _pose_response(model: PlateModel, q: np.ndarray) -> np.ndarray:
    """The pose (5,) that the front end reads per unit deviation of each of
    ``GEOMETRY_NAMES`` at pose ``q``, the rest offsets absorbing the deviation's rest
    image: shape (5, G); linearised."""
    rest_shift = model.jacobians(np.zeros(5)).geometry.reshape(-1, len(GEOMETRY_NAMES))
    sw = np.sqrt(_pose_fit_weights())
    jac = model.jacobians(q)
    residual = jac.geometry.reshape(rest_shift.shape) - rest_shift
    return np.linalg.lstsq(jac.pose.reshape(-1, 5) * sw[:, None], residual * sw[:, None],
                           rcond=None)[0]  # fmt: skip


def phi_response(model: PlateModel, phi_deg: float = CHECK_PHI_DEG) -> np.ndarray:
    """Error of phi at ``phi_deg`` per unit deviation of each of ``GEOMETRY_NAMES``,
    in each direction of CHECK_THETA_DEG, the rest offsets absorbing the deviation's
    rest image: shape (len(CHECK_THETA_DEG), G), deg per unit; linearised."""
    phi = math.radians(phi_deg)
    rows = []
    for theta in np.radians(CHECK_THETA_DEG):
        q = np.array([0.0, phi * math.cos(theta), phi * math.sin(theta), 0.0, 0.0])
        dq = _pose_response(model, q)
        rows.append(np.degrees(q[1] * dq[1] + q[2] * dq[2]) / phi)
    return np.array(rows)


def dz_gain_response(model: PlateModel, dz_mm: float = CHECK_DZ_MM) -> np.ndarray:
    """Relative error of dz read at ``dz_mm`` (no tilt) per unit deviation of each of
    ``GEOMETRY_NAMES`` (the file's value minus the truth), shape (G,); linearised.
    dz's gain less one: axial steps measure it directly."""
    return -_pose_response(model, np.array([dz_mm, 0.0, 0.0, 0.0, 0.0]))[0] / dz_mm


def phi_error_deg(model: PlateModel, deviation: np.ndarray, phi_deg: float = CHECK_PHI_DEG):
    """Error of phi at ``phi_deg`` when the model is off by ``deviation`` (of
    ``GEOMETRY_NAMES``), largest over CHECK_THETA_DEG (deg); see :func:`phi_response`."""
    return float(np.abs(phi_response(model, phi_deg) @ deviation).max())


def check_mismatch(rest, model: PlateModel, scatter_px: np.ndarray | None = None) -> MismatchCheck:
    """Check the rest points against the sensor file (see the module notes).

    Parameters
    ----------
    rest : RestReference
        The rest reference (its share maps give the corners' edges).
    model : PlateModel
        The sensor file's model.
    scatter_px : ndarray, shape (13,), optional
        Each point's per-frame scatter over the rest frames (px, per coordinate);
        None: one rest frame (SCATTER_ONE_FRAME_PX).

    Returns
    -------
    MismatchCheck
    """
    rest_uv = rest.uv.copy()
    rest_uv[:TIP], edge_sd = edge_corners(rest, model)

    r = (rest_uv - model.project(np.zeros(5), jacobian=False)[0]).reshape(-1)
    scatter = np.full(TIP + 1, SCATTER_ONE_FRAME_PX) if scatter_px is None else scatter_px
    bias = max(BIAS_PX, BIAS_PER_BLUR * np.nan_to_num(rest.share_blur_px))
    sigma = np.repeat(np.hypot(np.nan_to_num(scatter, nan=SCATTER_ONE_FRAME_PX), bias), 2)
    use = np.isfinite(r)
    rw = r[use] / sigma[use]
    jg = model.jacobians(np.zeros(5)).geometry.reshape(-1, len(GEOMETRY_NAMES))[use]
    tau = prior_scales(model)
    a = jg * tau / sigma[use, None]
    # Regularised least squares in prior units, min |w (r - J tau x) / sigma|^2 + |x|^2,
    # with Huber weights w: an edge that a spring or the cross disturbs counts less.
    w = np.ones_like(rw)
    for _ in range(HUBER_PASSES):
        aa = np.vstack([a * w[:, None], np.eye(len(tau))])
        x = np.linalg.lstsq(aa, np.concatenate([rw * w, np.zeros(len(tau))]), rcond=None)[0]
        e = np.abs(rw - a @ x)
        w = np.sqrt(np.minimum(1.0, HUBER_K / np.maximum(e, 1e-12)))
    deviation = x * tau
    # Each squared offset counts at most CHI2_CLIP: one disturbed edge cannot raise it alone.
    chi2 = float(np.mean(np.minimum(rw**2, CHI2_CLIP)))
    phi_err = phi_error_deg(model, deviation)
    order = np.argsort(-np.abs(x))
    suspects = [_describe(GEOMETRY_NAMES[k], deviation[k], model)
                for k in order[:MAX_SUSPECTS] if abs(x[k]) >= SUSPECT_SCALES]  # fmt: skip
    warned = bool(chi2 > CHI2_WARN and phi_err > PHI_ERROR_WARN_DEG)
    return MismatchCheck(
        float(np.sqrt(np.mean(r[use] ** 2))), float(np.sqrt(np.mean(sigma[use] ** 2))), chi2,
        phi_err, suspects or ["(no single parameter stands out)"], warned,
    )  # fmt: skip


def _describe(name: str, delta: float, model: PlateModel) -> str:
    """``camera.fx_px +2.9 %`` or ``plate.z_i_mm +0.55``."""
    if name in RELATIVE_TOLERANCE:
        base = model.camera.fx_px if name == "camera.fx_px" else model.camera.fy_px
        return f"{name} {100 * delta / base:+.1f} %"
    return f"{name} {delta:+.3g}"
