"""Shape reconstruction from the contact distance, eq. (12)."""

from __future__ import annotations

import numpy as np

from camwhisker.contact.gm import GMFit, deflection_mm

__all__ = ["reconstruct"]


def reconstruct(x_mm, r_hat_mm, phi_deg, travel_sign, gm: GMFit | None = None):
    """Contact point (x_hat, y_hat) from the base position, r_hat and phi.

    The whisker lags behind the base, so the contact lies behind it along the
    direction of travel by its lateral offset d: x_hat = x - sign(travel) d
    (eq. (12), the sign from the travel). Eq. (12) takes the whisker straight at
    phi: d = r_hat sin(phi), y_hat = r_hat cos(phi) along the rest axis. With the
    calibration's GM model ``gm`` it is bent as that model has it: d is the travel
    after which a stuck contact at r_hat tilts the base by phi (the model read
    backwards, :func:`~camwhisker.contact.gm.deflection_mm`), larger than r sin(phi)
    by the bending, and y_hat = sqrt(r_hat^2 - d^2) (the arc taken as its chord). y_hat is
    measured from the base where the axial force left it: the plate, pushed dz toward the
    camera, takes the base with it, so the contact lies dz nearer the base's rest position.

    Parameters
    ----------
    x_mm, r_hat_mm, phi_deg : array_like, shape (N,)
    travel_sign : float or array_like
        +1 for travel toward +x, -1 toward -x.
    gm : GMFit, optional

    Returns
    -------
    x_hat_mm, y_hat_mm : ndarray
        NaN where any input is NaN, or where the GM model puts the contact farther off the
        base's line than r_hat (r_hat outside its range).
    """
    phi = np.asarray(phi_deg, float)
    r = np.asarray(r_hat_mm, float)
    if gm is None:
        rad = np.radians(phi)
        d, y = r * np.sin(rad), r * np.cos(rad)
    else:
        d = deflection_mm(gm, r, phi)
        d = np.where(d <= r, d, np.nan)  # an offset past the whisker's length: no point
        y = np.sqrt(r * r - d * d)
    return np.asarray(x_mm, float) - np.sign(travel_sign) * d, y  # Eq. (12)
