"""Shape reconstruction from the contact distance, eq. (12), and the calibrated offset surface."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from camwhisker.contact.gm import GMFit, deflection_mm

__all__ = ["OffsetSurface", "fit_offset_surface", "reconstruct", "SURFACE_PHI_POWERS",
           "SURFACE_R_POWERS"]

# Powers of phi and r in the offset surface. The GM model's error in the offset grows with
# the bend, which is second order and up in phi and vanishes at phi 0; along r it is smooth.
SURFACE_PHI_POWERS = (2, 3, 4)
SURFACE_R_POWERS = (0, 1, 2, 3)
# Samples per coefficient below which the surface is not fitted: the calibration keeps the
# GM model's offset alone rather than a surface its own noise shaped.
MIN_SAMPLES_PER_TERM = 5


@dataclass(frozen=True)
class OffsetSurface:
    """What the GM model, read backwards, misses of a contact's offset from the base's line.

    d_true - deflection_mm(gm, r, phi) = sum c[i, j] (phi / phi_max)^p_i (r / r_max)^q_j,
    with p = :data:`SURFACE_PHI_POWERS`, q = :data:`SURFACE_R_POWERS` (or its first
    ``coef.shape[1]``). Evaluated with phi and r clipped to the calibrated box, where a
    polynomial holds.
    """

    coef: np.ndarray  # shape (len(SURFACE_PHI_POWERS), n_r_powers)
    phi_max_deg: float
    r_min_mm: float
    r_max_mm: float
    sd_before_mm: float = np.nan  # residual sd on the calibration, without and with it
    sd_after_mm: float = np.nan

    def __call__(self, r_mm, phi_deg) -> np.ndarray:
        return _design(np.clip(np.abs(phi_deg), 0.0, self.phi_max_deg),
                       np.clip(r_mm, self.r_min_mm, self.r_max_mm), self.phi_max_deg,
                       self.r_max_mm, self.coef.shape[1]) @ self.coef.ravel()


def _design(phi_deg, r_mm, phi_max_deg, r_max_mm, n_r):
    p = np.asarray(phi_deg, float)[..., None] / phi_max_deg
    r = np.asarray(r_mm, float)[..., None] / r_max_mm
    cols = [p**i * r**j for i in SURFACE_PHI_POWERS for j in SURFACE_R_POWERS[:n_r]]
    return np.concatenate(cols, axis=-1)


def fit_offset_surface(gm: GMFit, dx_mm, phi_deg, r_mm) -> OffsetSurface | None:
    """Least-squares :class:`OffsetSurface` from calibration pauses at known r.

    A calibration contact does not slide, so its offset from the base's line is the base's
    travel dx since the onset. r's powers stop one short of the number of distinct radii
    (a cubic needs four). None where the data cannot carry even the lowest surface.
    """
    dx, phi, r = (np.asarray(v, float).ravel() for v in (dx_mm, phi_deg, r_mm))
    resid = dx - deflection_mm(gm, r, phi)
    ok = np.isfinite(resid) & np.isfinite(phi) & np.isfinite(r)
    resid, phi, r = resid[ok], np.abs(phi[ok]), r[ok]
    n_r = min(len(SURFACE_R_POWERS), np.unique(np.round(r)).size - 1)
    if n_r < 1 or resid.size < MIN_SAMPLES_PER_TERM * len(SURFACE_PHI_POWERS) * n_r:
        return None
    phi_max, r_min, r_max = float(phi.max()), float(r.min()), float(r.max())
    a = _design(phi, r, phi_max, r_max, n_r)
    coef = np.linalg.lstsq(a, resid, rcond=None)[0]
    return OffsetSurface(coef.reshape(len(SURFACE_PHI_POWERS), n_r), phi_max, r_min, r_max,
                         sd_before_mm=float(np.std(resid)),
                         sd_after_mm=float(np.std(resid - a @ coef)))


def reconstruct(x_mm, r_hat_mm, phi_deg, dz_mm, travel_sign, gm: GMFit | None = None,
                surface: OffsetSurface | None = None):
    """Contact point (x_hat, y_hat) from the base position, r_hat, phi and dz.

    The whisker lags behind the base, so the contact lies behind it along the
    direction of travel by its lateral offset d: x_hat = x - sign(travel) d
    (eq. (12), the sign from the travel). Eq. (12) takes the whisker straight at
    phi: d = r_hat sin(phi), y_hat = r_hat cos(phi) along the rest axis. With the
    calibration's GM model ``gm`` it is bent as that model has it: d is the travel
    after which a stuck contact at r_hat tilts the base by phi (the model read
    backwards, :func:`~camwhisker.contact.gm.deflection_mm`), larger than r sin(phi)
    by the bending, plus the calibrated ``surface`` where there is one, and
    y_hat = sqrt(r_hat^2 - d^2) (the arc taken as its chord). y_hat is measured from the
    base's rest position: the plate, pushed dz toward the camera, takes the base with it, so
    the contact lies dz nearer: y_hat = ... - dz.

    Parameters
    ----------
    x_mm, r_hat_mm, phi_deg, dz_mm : array_like, shape (N,)
    travel_sign : float or array_like
        +1 for travel toward +x, -1 toward -x.
    gm : GMFit, optional
    surface : OffsetSurface, optional
        Used only with ``gm``.

    Returns
    -------
    x_hat_mm, y_hat_mm : ndarray
        NaN where any input is NaN, or where the model puts the contact farther off the
        base's line than r_hat (r_hat outside its range).
    """
    phi = np.asarray(phi_deg, float)
    r = np.asarray(r_hat_mm, float)
    if gm is None:
        rad = np.radians(phi)
        d, y = r * np.sin(rad), r * np.cos(rad)
    else:
        d = deflection_mm(gm, r, phi)
        if surface is not None:
            d = d + surface(r, phi)
        d = np.where(d <= r, d, np.nan)  # an offset past the whisker's length: no point
        y = np.sqrt(r * r - d * d)
    # Eq. (12)
    return np.asarray(x_mm, float) - np.sign(travel_sign) * d, y - np.asarray(dz_mm, float)
