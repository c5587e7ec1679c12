"""The paper's small-angle geometry, eqs. (2)-(7), implemented as printed.

Inputs are the tracked points of :mod:`camwhisker.vision.pose`: the cross's
projected width b_u is the distance in u between the +x and -x arm ends
(the mean of each arm's two end corners), and the tip position c is measured
from the principal point (docs/sensor.md section 2).

Two readings to be aware of (docs/sensor.md section 4):

- The angles of view of Table I are half angles (tan(26.95 deg) * 1258.79 =
  640 px), so rho of eq. (6) is half the pinhole millimetres per pixel at the
  tip's depth, and phi from eq. (7) is about half the true tilt's tangent.
- Eq. (5) as printed gives mu = 0.980 for Table I, the reciprocal of the
  table's 1.02.

Both are kept as printed; :mod:`camwhisker.vision.pose` is the exact model.

References
----------
.. [1] Weinkauf et al., "Identifying Contact Distance Uncertainty in Whisker
   Sensing with Tapered, Flexible Whiskers", section II.B, eqs. (2)-(7), Table I.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from camwhisker.sensor.file import Sensor
from camwhisker.sensor.model import N_SQUARE, TIP

__all__ = [
    "axial_deflection",
    "tip_shift_from_dz",
    "v_u_corrector",
    "mm_per_px",
    "rotation_magnitude",
    "projected_widths",
    "PaperRest",
    "PaperGeometry",
]


def axial_deflection(z_i_mm: float, b_ui_px, b_un_px):
    """dz_n = z_i (1 - b_ui / b_un), mm: eq. (2). Arrays broadcast."""
    return z_i_mm * (1.0 - np.asarray(b_ui_px, float) / np.asarray(b_un_px, float))  # Eq. (2)


def tip_shift_from_dz(z_i_mm: float, h_r_mm: float, c_i_px, dz_mm):
    """Pixel shift of the tip caused by dz alone, eqs. (3) (u) and (4) (v).

    Delta c = (z_i - h_r) c_i / ((z_i - h_r) - dz) - c_i, with c_i the tip's rest
    position from the principal point; apply to u and v alike.
    """
    d = z_i_mm - h_r_mm
    c_i = np.asarray(c_i_px, float)
    return d * c_i / (d - np.asarray(dz_mm, float)) - c_i  # Eqs. (3)-(4)


def _px_scale(z_i_mm, h_r_mm, res_px, aov_rad):
    return (z_i_mm - h_r_mm) / res_px * math.tan(aov_rad)


def v_u_corrector(z_i_mm, h_r_mm, u_res_px, v_res_px, u_aov_rad, v_aov_rad) -> float:
    """mu of eq. (5) as printed (0.980 for Table I)."""
    return _px_scale(z_i_mm, h_r_mm, u_res_px, u_aov_rad) / _px_scale(
        z_i_mm, h_r_mm, v_res_px, v_aov_rad
    )  # Eq. (5)


def mm_per_px(z_i_mm, h_r_mm, u_res_px, v_res_px, u_aov_rad, v_aov_rad) -> float:
    """rho of eq. (6), mm per pixel at the tip's depth (as printed)."""
    return 0.5 * (
        _px_scale(z_i_mm, h_r_mm, u_res_px, u_aov_rad)
        + _px_scale(z_i_mm, h_r_mm, v_res_px, v_aov_rad)
    )  # Eq. (6)


def rotation_magnitude(rho_mm_per_px: float, du_px, dv_px, mu: float, h_r_mm: float):
    """phi_n = arctan(rho sqrt(du^2 + (dv mu)^2) / h_r), radians: eq. (7)."""
    du, dv = np.asarray(du_px, float), np.asarray(dv_px, float)
    return np.arctan(rho_mm_per_px * np.sqrt(du**2 + (dv * mu) ** 2) / h_r_mm)  # Eq. (7)


def projected_widths(uv: np.ndarray) -> np.ndarray:
    """Projected widths (px) that eq. (2) compares: cross b_u, b_v, square t_u, t_v.

    Parameters
    ----------
    uv : ndarray, shape (13, 2)
        Tracked points (square corners, cross arm-end corners, tip); NaN where lost.

    Returns
    -------
    ndarray, shape (4,)
        NaN where one of a width's points is not tracked.
    """
    p = uv.tolist()  # a few sums: Python floats, without numpy's per-call cost
    arm = [((p[k][0] + p[k + 1][0]) / 2, (p[k][1] + p[k + 1][1]) / 2)
           for k in range(N_SQUARE, TIP, 2)]  # fmt: skip
    sq = p[:N_SQUARE]
    return np.array([
        arm[0][0] - arm[2][0],
        arm[1][1] - arm[3][1],
        (sq[1][0] + sq[2][0] - sq[0][0] - sq[3][0]) / 2,
        (sq[2][1] + sq[3][1] - sq[0][1] - sq[1][1]) / 2,
    ])  # fmt: skip


@dataclass(frozen=True)
class PaperRest:
    """The rest frame's measurements that eqs. (2)-(4) refer to.

    widths_px : ndarray, shape (4,)
        :func:`projected_widths` at rest (b_ui and its substitutes).
    tip_uv : ndarray, shape (2,)
        The tip's rest pixel (c_i before the principal point is removed).
    """

    widths_px: np.ndarray
    tip_uv: np.ndarray

    @classmethod
    def from_points(cls, uv: np.ndarray) -> PaperRest:
        """From the rest frame's tracked points, shape (13, 2)."""
        return cls(projected_widths(uv), np.array(uv[TIP], float))


@dataclass(frozen=True)
class PaperGeometry:
    """Eqs. (2)-(7) for one sensor, with the rest frame's measurements.

    The angles of view are read from the sensor's intrinsics as half angles,
    aov = atan(res / 2 / f), which reproduces Table I for the default sensor.
    """

    z_i_mm: float
    h_r_mm: float
    cx_px: float
    cy_px: float
    mu: float
    rho_mm_per_px: float

    @classmethod
    def from_sensor(cls, sensor: Sensor) -> PaperGeometry:
        cam, plate = sensor.camera, sensor.plate
        u_aov = math.atan(cam.width_px / 2 / cam.fx_px)
        v_aov = math.atan(cam.height_px / 2 / cam.fy_px)
        args = (plate.z_i_mm, plate.h_r_mm, cam.width_px, cam.height_px, u_aov, v_aov)
        return cls(plate.z_i_mm, plate.h_r_mm, cam.cx_px, cam.cy_px,
                   v_u_corrector(*args), mm_per_px(*args))  # fmt: skip

    def solve(self, b_ui_px: float, b_un_px, tip_i_uv: np.ndarray, tip_n_uv: np.ndarray):
        """(dz_mm, phi_rad, theta_rad) per frame.

        Parameters
        ----------
        b_ui_px : float
            Cross width in u at the rest frame.
        b_un_px : ndarray, shape (N,)
            Cross width in u per frame.
        tip_i_uv : ndarray, shape (2,)
            Tip pixel at the rest frame.
        tip_n_uv : ndarray, shape (N, 2)
            Tip pixel per frame.

        Returns
        -------
        dz_mm, phi_rad, theta_rad : ndarray, shape (N,)
            theta = atan2(delta_v, delta_u), the image direction of the tip's
            motion after the dz correction.
        """
        dz = axial_deflection(self.z_i_mm, b_ui_px, b_un_px)
        c_i = np.asarray(tip_i_uv, float) - (self.cx_px, self.cy_px)
        tip = np.atleast_2d(np.asarray(tip_n_uv, float))
        shift = tip_shift_from_dz(self.z_i_mm, self.h_r_mm, c_i[None, :], np.asarray(dz)[..., None])
        delta = tip - (self.cx_px, self.cy_px) - c_i - shift
        phi = rotation_magnitude(self.rho_mm_per_px, delta[:, 0], delta[:, 1], self.mu, self.h_r_mm)
        theta = np.arctan2(delta[:, 1], delta[:, 0])
        return dz, phi, theta

    def pose_from_points(self, rest: PaperRest, uv: np.ndarray) -> tuple[float, float, float]:
        """Eqs. (2)-(7) on one frame's tracked points: (dz_mm, phi_deg, theta_deg).

        Eq. (2) takes b_u; where an arm end is hidden it substitutes b_v, then the
        square's t_u, t_v ("any can be substituted", section II.B). NaN where no
        width or the tip is untracked.

        Parameters
        ----------
        rest : PaperRest
        uv : ndarray, shape (13, 2)
        """
        widths_n = projected_widths(uv)
        usable = np.isfinite(widths_n) & np.isfinite(rest.widths_px)
        if not (usable.any() and np.isfinite(uv[TIP]).all()):
            return (math.nan, math.nan, math.nan)
        k = int(np.argmax(usable))  # Eq. (2): the first usable width, b_u first
        dz, phi, theta = self.solve(rest.widths_px[k], widths_n[k : k + 1], rest.tip_uv,
                                    uv[TIP][None, :])  # fmt: skip
        return float(dz[0]), math.degrees(phi[0]), math.degrees(theta[0])
