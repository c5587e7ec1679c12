"""A tapered, flexible whisker on a linear spring base: small-deflection beam and elastica.

Planar lab frame (mm): the whisker base travels along +x on the line y = 0; at
rest the whisker points along +y. Angles ``beta`` are tangent directions
measured counter-clockwise from +x, so the rest direction is pi/2. A signed
base rotation ``phi_rad`` > 0 leans the whisker toward -x (it lags behind a
base moving in +x); the plate's rotation magnitude is ``phi_deg = |phi|``.

The whisker is a truncated cone: radius R(s) = R0 (1 - s / L_a) with the apex
length L_a = l_w / (1 - tip_ratio), so EI(s) = EI0 (1 - s / L_a)^4. The base is
a concentrated rotational compliance (phi = M(0) / k_phi) and an axial spring
(dz = F_axial / k_z, positive toward the camera), both linear as in docs/sensor.md.

Two models, each used where it is accurate:

- :func:`beam_peg_response`: Euler-Bernoulli small deflection, closed form for
  the cone (see the derivation in the docstring). Exact as phi, the bending
  slope and dz all go to zero.
- :func:`solve_elastica`: the planar inextensible elastica with a point load,
  solved by shooting (fixed-step RK4 + :func:`scipy.optimize.fsolve`).

``tests/test_mechanics.py::test_beam_and_elastica_part`` measures where the two
part; :data:`PHI_LINEAR_MAX_DEG` is set from that measurement.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "WhiskerMechanics",
    "ContactSolution",
    "ElasticaError",
    "PHI_LINEAR_MAX_DEG",
    "beam_dz_from_phi",
    "beam_peg_response",
    "solve_elastica",
]

# Below this base rotation the small-deflection beam and the elastica agree to
# better than 0.02 deg in phi (a tenth of the paper's 0.22 deg phi noise) for
# every paper radius; measured by tests/test_mechanics.py::test_beam_and_elastica_part.
PHI_LINEAR_MAX_DEG = 5.0

# RK4 steps along the loaded part of the whisker. 64 steps agree with 1024 to
# 1e-6 deg in phi and 1e-6 mm in dz (tests/test_mechanics.py::test_elastica_converged).
ELASTICA_STEPS = 64

# fsolve residuals are dimensionless (lengths / l_w, moments / k_phi, angles):
# 1e-10 is far below every noise level of the sensor.
_SOLVE_XTOL = 1e-10


class ElasticaError(ValueError):
    """The elastica shooting problem did not converge for the given scene."""


@dataclass(frozen=True)
class WhiskerMechanics:
    """Geometry, material and base springs of the simulated whisker.

    The defaults give phi up to ~20-30 deg and dz up to ~1 mm over the
    calibration runs (1 mm steps, <= 40 mm travel), like the paper's data:
    a 1.5 mm-base cone of a stiff polymer (E = 3 GPa) on a base much softer in
    rotation than the whisker (k_phi / EI0 = 1e-3 / mm), so the whisker bends
    a few millimetres while the plate turns, and an axial spring soft enough
    to turn the few-percent axial share of the contact force into ~1 mm.
    """

    length_mm: float = 150.0
    base_diameter_mm: float = 1.5
    tip_ratio: float = 0.2
    youngs_modulus_n_per_mm2: float = 3000.0
    k_phi_nmm_per_rad: float = 0.7456
    k_z_n_per_mm: float = 1.2e-4
    # A stiff polymer's density (nylon, PLA: 1.1-1.25 g/cm^3), in the N-mm-s unit system.
    density_t_per_mm3: float = 1.2e-9

    @property
    def ei0_nmm2(self) -> float:
        """Bending stiffness at the base, E * pi d^4 / 64 (N mm^2)."""
        return self.youngs_modulus_n_per_mm2 * math.pi * self.base_diameter_mm**4 / 64.0

    @property
    def apex_mm(self) -> float:
        """Length L_a of the full cone that the whisker is cut from (mm)."""
        return self.length_mm / (1.0 - self.tip_ratio)

    @property
    def beta_per_mm(self) -> float:
        """Rotational base stiffness over base bending stiffness, k_phi / EI0 (1/mm)."""
        return self.k_phi_nmm_per_rad / self.ei0_nmm2

    def area_mm2(self, s_mm):
        """Cross-section A(s) = pi R0^2 (1 - s / L_a)^2 along the arc length."""
        r0 = 0.5 * self.base_diameter_mm
        return math.pi * r0**2 * (1.0 - np.asarray(s_mm) / self.apex_mm) ** 2

    def ei_nmm2(self, s_mm):
        """Bending stiffness EI(s) = EI0 (1 - s / L_a)^4 along the arc length."""
        return self.ei0_nmm2 * (1.0 - np.asarray(s_mm) / self.apex_mm) ** 4


def beam_dz_from_phi(mech: WhiskerMechanics, r_mm, phi_rad):
    """Small-deflection axial deflection dz (mm) for a peg at r and base rotation phi.

    Same beam as :func:`beam_peg_response`: F = k_phi phi / r,
    psi = F r^2 (1 + 2a) / (6 EI0 a^2), dz = F sin(psi) / k_z.
    """
    r = np.asarray(r_mm, dtype=float)
    a = 1.0 - r / mech.apex_mm
    force = mech.k_phi_nmm_per_rad * np.asarray(phi_rad, dtype=float) / r
    psi = force * r**2 * (1.0 + 2.0 * a) / (6.0 * mech.ei0_nmm2 * a**2)
    return force * np.sin(psi) / mech.k_z_n_per_mm


def beam_peg_response(mech: WhiskerMechanics, r_mm, dx_mm, k_obj_n_per_mm=np.inf):
    """Small-deflection response to a peg at radial distance r pushed by dx.

    For a cone EI0 (1 - s/L_a)^4 loaded by a lateral force F at s = r (a = 1 - r/L_a):

    - lateral deflection at r relative to the base tangent:
      w = F r^3 / (3 EI0 a)      (integral of (r - s)^2 / EI(s))
    - slope at r relative to the base tangent:
      psi = F r^2 (1 + 2a) / (6 EI0 a^2)
    - base moment M = F r = k_phi phi; object spring (if any) takes u = F / k_obj.

    Compatibility dx = phi r + w + u gives
    phi = dx / (r + beta r^2 / (3a) + k_phi / (r k_obj)), with beta = k_phi / EI0,
    and the axial force F_z = F sin(psi) gives dz = F_z / k_z.

    Parameters
    ----------
    mech : WhiskerMechanics
    r_mm, dx_mm : array_like
        Contact distance and base travel since first contact (>= 0).
    k_obj_n_per_mm : float or array_like
        Stiffness of the contacted object; ``inf`` for a rigid peg.

    Returns
    -------
    phi_rad, dz_mm, force_n : ndarray
    """
    r = np.asarray(r_mm, dtype=float)
    dx = np.asarray(dx_mm, dtype=float)
    a = 1.0 - r / mech.apex_mm
    k_obj = np.asarray(k_obj_n_per_mm, dtype=float)
    object_compliance = np.where(np.isinf(k_obj), 0.0, mech.k_phi_nmm_per_rad / (r * k_obj))
    dx_per_phi = r + mech.beta_per_mm * r**2 / (3.0 * a) + object_compliance
    phi = dx / dx_per_phi
    force = mech.k_phi_nmm_per_rad * phi / r
    return phi, beam_dz_from_phi(mech, r, phi), force


@dataclass(frozen=True)
class ContactSolution:
    """Equilibrium of the whisker for one base position.

    ``unknowns`` (phi_rad, force * l_w / k_phi, force angle, s_contact / l_w)
    seed the next solve of a quasi-static sweep.
    """

    phi_rad: float
    dz_mm: float
    force_n: float
    s_contact_mm: float
    contact_xy_mm: tuple[float, float]
    base_xy_mm: tuple[float, float]
    beta_contact_rad: float
    unknowns: tuple[float, float, float, float]

    @property
    def phi_deg(self) -> float:
        return abs(math.degrees(self.phi_rad))

    @property
    def r_mm(self) -> float:
        """Radial contact distance: straight-line distance base -> contact point."""
        return math.hypot(
            self.contact_xy_mm[0] - self.base_xy_mm[0], self.contact_xy_mm[1] - self.base_xy_mm[1]
        )


def _integrate(mech: WhiskerMechanics, s_end, base_x, base_y, beta0, m0, fx, fy, n):
    """RK4 along 0 <= s <= s_end of x' = cos b, y' = sin b, b' = M / EI, M' = Fx sin b - Fy cos b.

    M(s) is the internal moment (N mm, counter-clockwise positive) that the
    part of the whisker beyond s exerts on the part before it; a force F at
    s_c gives M(s) = (r_c - r(s)) x F, hence M' above and M(s_c) = 0.
    """
    return _rk4_compiled()(float(s_end), float(base_x), float(base_y), float(beta0),
                           float(m0), float(fx), float(fy), int(n), mech.ei0_nmm2,
                           1.0 / mech.apex_mm)  # fmt: skip


@functools.cache
def _rk4_compiled():
    """:func:`_rk4` compiled by numba (imported here: the simulator's users alone pay it)."""
    import numba

    return numba.njit(cache=True)(_rk4)


def _rk4(s_end, base_x, base_y, beta0, m0, fx, fy, n, ei0, inv_apex):
    """:func:`_integrate`'s loop, on plain numbers."""
    h = s_end / n
    x, y, b, m = base_x, base_y, beta0, m0
    for i in range(n):
        s = i * h
        e1 = ei0 * (1.0 - s * inv_apex) ** 4
        e2 = ei0 * (1.0 - (s + 0.5 * h) * inv_apex) ** 4
        e3 = ei0 * (1.0 - (s + h) * inv_apex) ** 4
        c1, s1 = math.cos(b), math.sin(b)
        kb1, km1 = m / e1, fx * s1 - fy * c1
        b2, m2 = b + 0.5 * h * kb1, m + 0.5 * h * km1
        c2, s2 = math.cos(b2), math.sin(b2)
        kb2, km2 = m2 / e2, fx * s2 - fy * c2
        b3, m3 = b + 0.5 * h * kb2, m + 0.5 * h * km2
        c3, s3 = math.cos(b3), math.sin(b3)
        kb3, km3 = m3 / e2, fx * s3 - fy * c3
        b4, m4 = b + h * kb3, m + h * km3
        c4, s4 = math.cos(b4), math.sin(b4)
        kb4, km4 = m4 / e3, fx * s4 - fy * c4
        x += h / 6.0 * (c1 + 2 * c2 + 2 * c3 + c4)
        y += h / 6.0 * (s1 + 2 * s2 + 2 * s3 + s4)
        b += h / 6.0 * (kb1 + 2 * kb2 + 2 * kb3 + kb4)
        m += h / 6.0 * (km1 + 2 * km2 + 2 * km3 + km4)
    return x, y, b, m


def _state(mech: WhiskerMechanics, base_x_mm, u, n):
    """Integrate the whisker for unknowns u; return contact state and forces."""
    phi, f, alpha, sigma = u
    length = mech.length_mm
    force = f * mech.k_phi_nmm_per_rad / length
    fx, fy = force * math.cos(alpha), force * math.sin(alpha)
    beta0 = 0.5 * math.pi + phi
    t0x, t0y = math.cos(beta0), math.sin(beta0)
    # Axial spring: a force pointing back along the base tangent pushes the
    # plate toward the camera (dz > 0), which moves the base by -dz along t0.
    dz = -(fx * t0x + fy * t0y) / mech.k_z_n_per_mm
    bx, by = base_x_mm - dz * t0x, -dz * t0y
    m0 = mech.k_phi_nmm_per_rad * phi
    s_c = max(sigma, 1e-6) * length
    xc, yc, bc, mc = _integrate(mech, s_c, bx, by, beta0, m0, fx, fy, n)
    return dict(
        phi=phi, dz=dz, force=force, fx=fx, fy=fy, s_c=s_c, xc=xc, yc=yc, bc=bc, mc=mc, bx=bx, by=by
    )


def solve_elastica(
    mech: WhiskerMechanics,
    base_x_mm: float,
    constraint,
    guess,
    n_steps: int = ELASTICA_STEPS,
) -> ContactSolution:
    """Solve the elastica for one base position under a contact constraint.

    Parameters
    ----------
    mech : WhiskerMechanics
    base_x_mm : float
        Stage position of the whisker base.
    constraint : callable
        ``constraint(state, u) -> (r1, r2, r3)``: three dimensionless residuals
        that fix the contact (e.g. contact point on a peg and force normal to
        the whisker). The fourth residual, M(s_c) = 0, is always added.
    guess : sequence of 4 floats
        Start for (phi_rad, force * l_w / k_phi, force angle rad, s_c / l_w).

    Raises
    ------
    ElasticaError
        fsolve did not converge.
    """
    k_phi = mech.k_phi_nmm_per_rad

    def residual(u):
        st = _state(mech, base_x_mm, u, n_steps)
        return [st["mc"] / k_phi, *constraint(st, u)]

    from scipy.optimize import fsolve  # here: see camwhisker.contact.gm on import time

    u, info, ier, msg = fsolve(residual, np.asarray(guess, float), full_output=True,
                               xtol=_SOLVE_XTOL)
    if ier != 1 or np.max(np.abs(info["fvec"])) > 1e-7:
        raise ElasticaError(f"elastica did not converge at base x = {base_x_mm:.3f} mm: {msg}")
    st = _state(mech, base_x_mm, u, n_steps)
    return ContactSolution(
        phi_rad=st["phi"],
        dz_mm=st["dz"],
        force_n=st["force"],
        s_contact_mm=st["s_c"],
        contact_xy_mm=(st["xc"], st["yc"]),
        base_xy_mm=(st["bx"], st["by"]),
        beta_contact_rad=st["bc"],
        unknowns=tuple(float(v) for v in u),
    )
