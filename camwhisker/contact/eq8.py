"""The paper's eq. (8), the Gradient-Moment relation, both ways.

With phi in degrees and dx in mm::

    r_GM = C (dx / phi) l_w / (l_w + C dx / phi)

:func:`r_gm_eq8` gives the contact distance (the contact back end's GM
estimate, :mod:`camwhisker.contact.gm`); :func:`eq8_phi_deg` gives the
rotation that produces a distance (the simulator's eq.-8 runs,
:mod:`camwhisker.sim.mechanics.experiment`); :func:`eq8_dx_mm` the travel, which is
the contact's lateral offset (:mod:`camwhisker.contact.shape`). All import it
from here, so the directions stay one equation.

References
----------
Eq. (8): "Identifying Contact Distance Uncertainty in Whisker Sensing with
Tapered, Flexible Whiskers" (the seed paper of this project).
"""

from __future__ import annotations

import numpy as np

__all__ = ["PHI_MIN_DEG", "defined", "r_gm_eq8", "eq8_phi_deg", "eq8_dx_mm"]

# Below 1 deg the paper's 0.22 deg phi noise alone is > 20 % of phi per frame;
# pause medians bring it to ~5 %. No GM (or MF) estimate is made below it.
PHI_MIN_DEG = 1.0


def defined(dx, phi_deg, phi_min_deg):
    """Where eq. (8) and its alternatives are defined: finite, phi >= phi_min_deg, dx > 0."""
    return np.isfinite(dx) & np.isfinite(phi_deg) & (phi_deg >= phi_min_deg) & (dx > 0.0)


def r_gm_eq8(dx_mm, phi_deg, c, l_w_mm, phi_min_deg=PHI_MIN_DEG):
    """Radial contact distance from eq. (8).

    Parameters
    ----------
    dx_mm : array_like
        Base travel since first contact (mm).
    phi_deg : array_like
        Base rotation magnitude (deg).
    c : float
        The GM constant C (mm^-1 deg per mm of travel, 132 in the paper).
    l_w_mm : float
        Whisker length.

    Returns
    -------
    ndarray
        r_GM in (0, l_w) where defined, NaN elsewhere.
    """
    dx = np.asarray(dx_mm, dtype=float)
    phi = np.asarray(phi_deg, dtype=float)
    dx, phi = np.broadcast_arrays(dx, phi)
    ok = defined(dx, phi, phi_min_deg)
    q = np.divide(dx, phi, out=np.full(dx.shape, np.nan), where=ok)
    cq = c * q
    return np.divide(cq * l_w_mm, l_w_mm + cq, out=np.full(dx.shape, np.nan), where=ok)  # Eq. (8)


def eq8_phi_deg(r_mm, dx_mm, c, l_w_mm):
    """Eq. (8) read backwards: the phi (deg) that gives r_GM = r after travel dx.

    From eq. (8), C dx / phi = r l_w / (l_w - r), so phi = C dx (l_w - r) / (r l_w).
    This is the same equation as :func:`r_gm_eq8` (used to generate eq.-8 data).
    """
    r = np.asarray(r_mm, dtype=float)
    return c * np.asarray(dx_mm, dtype=float) * (l_w_mm - r) / (r * l_w_mm)


def eq8_dx_mm(r_mm, phi_deg, c, l_w_mm):
    """Eq. (8) read for the travel: the dx after which a stuck contact at r tilts the base by
    phi, dx = phi r l_w / (C (l_w - r)); the contact's lateral offset from the base line.
    NaN outside 0 < r < l_w."""
    r = np.asarray(r_mm, dtype=float)
    r, phi = np.broadcast_arrays(r, np.asarray(phi_deg, dtype=float))
    ok = (r > 0.0) & (r < l_w_mm)
    return np.divide(phi * r * l_w_mm, c * (l_w_mm - r), out=np.full(r.shape, np.nan), where=ok)
