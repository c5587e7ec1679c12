"""The whisker's first bending mode: the frequency at which it rings when let go.

The whisker of :class:`~camwhisker.sim.mechanics.whisker.WhiskerMechanics` (a cone,
EI(s) = EI0 (1 - s / L_a)^4, mass per length rho A(s) = rho A0 (1 - s / L_a)^2)
on its rotational base spring k_phi, the base held laterally. Rayleigh-Ritz
with the polynomials w_k(s) = (s / l_w)^k, k = 1..N (k = 1: the rigid turn on
the spring), on Gauss-Legendre nodes:

    K_ij = int EI w_i'' w_j'' ds + k_phi w_i'(0) w_j'(0),   M_ij = int rho A w_i w_j ds,

and omega^2 is the smallest eigenvalue of K c = omega^2 M c. The plate's own
inertia is left out (it would lower the frequency).

Limits, tested by hand-worked values (tests/test_texture.py): a rigid whisker,
omega^2 = k_phi / int rho A s^2 ds; a uniform rod clamped at the base,
omega = 1.8751^2 sqrt(EI / (rho A l_w^4)).
"""

from __future__ import annotations

import math

import numpy as np

from camwhisker.sim.mechanics.whisker import WhiskerMechanics

__all__ = ["first_mode_hz", "RITZ_TERMS"]

# Polynomial terms: 8 agree with 12 to 1e-6 of the frequency for the default whisker
# and for both limits above.
RITZ_TERMS = 8
_NODES = 64


def first_mode_hz(mech: WhiskerMechanics, terms: int = RITZ_TERMS) -> float:
    """Undamped natural frequency (Hz) of the whisker's first bending mode on its base spring."""
    from scipy.linalg import eigh

    length = mech.length_mm
    x, w = np.polynomial.legendre.leggauss(_NODES)
    s = 0.5 * length * (x + 1.0)
    ds = 0.5 * length * w
    k = np.arange(1, terms + 1)[:, None]
    xi = s[None, :] / length
    shape = xi**k  # (terms, nodes)
    curvature = np.where(k >= 2, k * (k - 1) * xi ** np.maximum(k - 2, 0), 0.0) / length**2
    ei = mech.ei_nmm2(s) * ds
    mass = mech.density_t_per_mm3 * mech.area_mm2(s) * ds
    stiff = (curvature * ei) @ curvature.T
    stiff[0, 0] += mech.k_phi_nmm_per_rad / length**2  # w_1'(0) = 1 / l_w, the others 0
    inertia = (shape * mass) @ shape.T
    omega2 = eigh(stiff, inertia, eigvals_only=True, subset_by_index=(0, 0))[0]
    return math.sqrt(omega2) / (2.0 * math.pi)
