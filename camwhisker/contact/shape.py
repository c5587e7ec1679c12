"""Shape reconstruction from the contact distance, eq. (12)."""

from __future__ import annotations

import numpy as np

__all__ = ["reconstruct"]


def reconstruct(x_mm, r_hat_mm, phi_deg, travel_sign):
    """Contact point (x_hat, y_hat) from the base position, r_hat and phi.

    The whisker lags behind the base, so the contact lies behind it along the
    direction of travel: x_hat = x - sign(travel) r_hat sin(phi) (eq. (12),
    the sign from the travel), and y_hat = r_hat cos(phi) along the rest axis.

    Parameters
    ----------
    x_mm, r_hat_mm, phi_deg : array_like, shape (N,)
    travel_sign : float or array_like
        +1 for travel toward +x, -1 toward -x.

    Returns
    -------
    x_hat_mm, y_hat_mm : ndarray
        NaN where any input is NaN.
    """
    phi = np.radians(np.asarray(phi_deg, float))
    r = np.asarray(r_hat_mm, float)
    x_hat = np.asarray(x_mm, float) - np.sign(travel_sign) * r * np.sin(phi)  # Eq. (12)
    return x_hat, r * np.cos(phi)
