"""The plate's suspension: four serpentine springs (Table I) -> axial and rotational stiffness.

The springs are laser-cut from one acrylic sheet and carry the plate's
out-of-plane motion (dz, and the tilt phi about an in-plane axis). Each spring
is a planar grid of straight beams loaded out of its plane, so its stiffness
follows from the direct stiffness method for grillages (McGuire, Gallagher &
Ziemian, *Matrix Structural Analysis*, 2nd ed., 2000, sec. 4.6 and 5.2): every
beam has Euler-Bernoulli bending (EI) about the sheet's in-plane axis and
Saint-Venant torsion (GJ); three degrees of freedom per node (w, rx, ry). This
is the serpentine-spring analysis of Fedder (G. K. Fedder, *Simulation of
Microelectromechanical Systems*, PhD thesis, UC Berkeley, 1994, ch. 3), done
numerically instead of with his closed forms, so the hub's rotation and the
plate's four-spring layout are in it with no further approximation. A beam
element is exact for end loads, so one element per straight segment suffices.

Geometry (Table I; the paper does not draw the spring, so the reading is
stated here): a spring runs radially out from the plate's hub. It is ``turns``
meanders, each a connector of length ``pitch_mm`` along the spring's run
followed by a leg of length ``length_mm`` across it (legs alternate sides), then
a last connector into the housing, where it is clamped. Beams are
``width_mm`` wide in the sheet and ``thickness_mm`` thick (the sheet).
The four springs leave the hub at 45, 135, 225 and 315 deg (docs/sensor.md
section 3), and the hub is rigid (the plate).

Small deflections: F_z = k_z dz and M_b = k_phi phi (linear, as the paper
found, sec. II.C); the four-fold layout makes k_phi the same for every tilt
direction theta and leaves dz and tilt uncoupled.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

__all__ = [
    "SpringDesign",
    "Stiffness",
    "SpringDesignError",
    "rect_torsion_constant",
    "grillage_element",
    "serpentine_centreline",
    "end_stiffness",
    "suspension_stiffness",
]


class SpringDesignError(ValueError):
    """A spring design that cannot be built; the message names the key."""


@dataclass(frozen=True)
class SpringDesign:
    """The suspension's design: Table I's spring values, their material and layout.

    Table I: pitch p = 2.6 mm, spring length l = 1.5 mm, width w = 0.75 mm,
    thickness t = 0.75 mm, n = 12 turns; four springs (sec. II.A). The material
    and the layout are not in Table I: cast acrylic (PMMA, E 3.2 GPa and
    Poisson's ratio 0.37, mid-range of its datasheets), and the hub radius of the
    nominal scene's springs (4.3 mm, where they leave the plate beside the
    5 mm square).
    """

    pitch_mm: float = 2.6
    length_mm: float = 1.5
    width_mm: float = 0.75
    thickness_mm: float = 0.75
    turns: int = 12
    springs: int = 4
    youngs_modulus_n_per_mm2: float = 3200.0
    poisson_ratio: float = 0.37
    hub_radius_mm: float = 4.3

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "poisson_ratio":
                if not 0.0 <= value < 0.5:
                    raise SpringDesignError(f"poisson_ratio: must lie in [0, 0.5), got {value}")
            elif f.name in ("turns", "springs"):
                if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                    raise SpringDesignError(f"{f.name}: must be a positive integer, got {value!r}")
            elif not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise SpringDesignError(f"{f.name}: must be a positive number, got {value!r}")
        if self.springs < 3:
            raise SpringDesignError(f"springs: fewer than 3 cannot hold a tilt, got {self.springs}")

    @property
    def shear_modulus_n_per_mm2(self) -> float:
        """G = E / (2 (1 + nu)), isotropic material."""
        return self.youngs_modulus_n_per_mm2 / (2.0 * (1.0 + self.poisson_ratio))

    @property
    def ei_nmm2(self) -> float:
        """Out-of-plane bending stiffness of a beam, E w t^3 / 12 (N mm^2)."""
        return self.youngs_modulus_n_per_mm2 * self.width_mm * self.thickness_mm**3 / 12.0

    @property
    def gj_nmm2(self) -> float:
        """Torsional stiffness of a beam, G J (N mm^2)."""
        return self.shear_modulus_n_per_mm2 * rect_torsion_constant(self.width_mm,
                                                                    self.thickness_mm)


@dataclass(frozen=True)
class Stiffness:
    """The suspension's stiffness: axial k_z (N/mm) and rotational k_phi (N mm/rad).

    ``source`` says where the values come from ("model" or the fitted file);
    the intervals are 95 % confidence intervals where fitted (NaN otherwise).
    """

    k_z_n_per_mm: float
    k_phi_nmm_per_rad: float
    source: str = "model"
    k_z_ci95: tuple[float, float] = (math.nan, math.nan)
    k_phi_ci95: tuple[float, float] = (math.nan, math.nan)

    def fz_mN(self, dz_mm):
        """Axial force (mN) from dz: F_z = k_z dz (small deflection)."""
        return 1e3 * self.k_z_n_per_mm * np.asarray(dz_mm, float)

    def mb_Nmm(self, phi_deg):
        """Bending moment magnitude (N mm) from phi: M_b = k_phi phi (small deflection)."""
        return self.k_phi_nmm_per_rad * np.radians(np.asarray(phi_deg, float))

    def columns(self, dz_mm, phi_deg) -> dict:
        """The tables' force columns: ``fz_mN`` and ``mb_Nmm`` (NaN where the signal is)."""
        return {"fz_mN": self.fz_mN(dz_mm), "mb_Nmm": self.mb_Nmm(phi_deg)}


def rect_torsion_constant(a_mm: float, b_mm: float) -> float:
    """Saint-Venant torsion constant J (mm^4) of an a x b rectangle.

    J = a b^3 [1/3 - 0.21 (b/a) (1 - b^4 / (12 a^4))] with a >= b (Roark's
    Formulas for Stress and Strain, 7th ed., table 20 case 4); within 0.5 % of the
    series solution for every aspect ratio (0.1406 a^4 for a square).
    """
    a, b = max(a_mm, b_mm), min(a_mm, b_mm)
    return a * b**3 * (1.0 / 3.0 - 0.21 * (b / a) * (1.0 - b**4 / (12.0 * a**4)))


def grillage_element(p0, p1, ei: float, gj: float) -> np.ndarray:
    """Stiffness of one grillage beam in global DOFs (w0, rx0, ry0, w1, rx1, ry1), shape (6, 6).

    w is the out-of-plane displacement, (rx, ry) the rotation vector's in-plane
    components (right-handed, z out of the sheet). Along the beam (unit e, length
    L), with r_e the rotation about e (twist) and r_n the rotation about the
    in-plane normal n = z x e, the slope is dw/ds = -r_n. Bending: the cubic
    beam element (EI/L^3 [12, 6L; 6L, 4L^2] blocks); torsion: GJ/L on r_e.
    """
    d = np.asarray(p1, float) - np.asarray(p0, float)
    length = float(np.hypot(*d))
    c, s = d / length
    # Local DOFs (w, r_e, r_n) from global (w, rx, ry): r_e = c rx + s ry, r_n = -s rx + c ry.
    rot = np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])
    t = np.zeros((6, 6))
    t[:3, :3] = t[3:, 3:] = rot
    L = length
    b = ei / L**3
    # Bending in (w, slope) with slope = -r_n: sign-flip the slope rows/columns.
    kb = b * np.array([[12, 6 * L, -12, 6 * L], [6 * L, 4 * L**2, -6 * L, 2 * L**2],
                       [-12, -6 * L, 12, -6 * L], [6 * L, 2 * L**2, -6 * L, 4 * L**2]])
    flip = np.diag([1.0, -1.0, 1.0, -1.0])
    kb = flip @ kb @ flip
    k = np.zeros((6, 6))
    idx = [0, 2, 3, 5]
    k[np.ix_(idx, idx)] = kb
    kt = gj / L
    k[1, 1] = k[4, 4] = kt
    k[1, 4] = k[4, 1] = -kt
    return t.T @ k @ t


def serpentine_centreline(design: SpringDesign) -> np.ndarray:
    """Node positions (mm) of one spring in its own frame, shape (2 turns + 2, 2).

    u along the spring's run from the hub (u = 0) outward, v across it; the
    first node is the hub, the last the clamp (module docstring).
    """
    p, leg = design.pitch_mm, design.length_mm
    nodes = [(0.0, 0.0)]
    v = 0.0
    for k in range(design.turns):
        u = (k + 1) * p
        nodes.append((u, v))
        v = leg if v == 0.0 else 0.0  # legs alternate sides of the run
        nodes.append((u, v))
    nodes.append(((design.turns + 1) * p, v))
    return np.array(nodes)


def end_stiffness(nodes, ei: float, gj: float) -> np.ndarray:
    """Stiffness (3, 3) at the first node of a chain of beams clamped at its last node.

    The chain's stiffness matrix is assembled, the clamp's DOFs removed, and
    the free end's flexibility (the inverse's first 3x3 block) inverted: the
    static condensation onto (w, rx, ry) of the first node.
    """
    nodes = np.asarray(nodes, float)
    n = nodes.shape[0]
    k = np.zeros((3 * n, 3 * n))
    for i in range(n - 1):
        dofs = np.r_[3 * i:3 * i + 6]
        k[np.ix_(dofs, dofs)] += grillage_element(nodes[i], nodes[i + 1], ei, gj)
    free = 3 * (n - 1)
    flexibility = np.linalg.solve(k[:free, :free], np.eye(free)[:, :3])[:3]
    return np.linalg.inv(flexibility)


def suspension_stiffness(design: SpringDesign | None = None) -> Stiffness:
    """k_z and k_phi of the whole suspension: every spring's end stiffness on the rigid hub.

    Spring i leaves the hub at angle beta_i = 45 + 360 i / springs deg, at
    radius R. A plate motion (w0, wx, wy) (translation along z and tilt vector)
    moves its end by w = w0 + wx y_i - wy x_i and turns it by (wx, wy); the
    plate's stiffness is the sum of A_i^T K_i A_i over the springs.
    """
    design = design or SpringDesign()
    k_local = end_stiffness(serpentine_centreline(design), design.ei_nmm2, design.gj_nmm2)
    total = np.zeros((3, 3))
    for i in range(design.springs):
        beta = math.radians(45.0) + 2.0 * math.pi * i / design.springs
        c, s = math.cos(beta), math.sin(beta)
        x, y = design.hub_radius_mm * c, design.hub_radius_mm * s
        # The spring's local end DOFs (w, r_u, r_v) from the plate's (w0, wx, wy).
        a = np.array([[1.0, y, -x], [0.0, c, s], [0.0, -s, c]])
        total += a.T @ k_local @ a
    return Stiffness(k_z_n_per_mm=float(total[0, 0]),
                     k_phi_nmm_per_rad=float(0.5 * (total[1, 1] + total[2, 2])))
