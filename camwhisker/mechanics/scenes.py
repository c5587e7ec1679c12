"""Scenes for the stage experiments and their quasi-static sweeps.

A scene is what the whisker touches while its base travels along +x:

- :class:`PegScene`: a point peg at (x_mm, r_mm), rigid or on a spring (the
  compliant "pipe cleaner" of the paper). The object point stays fixed (or
  moves with its spring), so the GM assumption holds for the rigid peg.
- :class:`BoxScene`: the lower-left corner of a box; the whisker pivots on
  the corner (a rigid point contact) and the box outline is two rays.
- :class:`CircleScene`: a circular cross-section (a water bottle); the
  whisker stays tangent to it, so the contact point slides along the circle as
  the whisker turns: the GM's fixed-contact assumption fails more and more.

:func:`sweep` solves one equilibrium per base position, continuing each solve
from the last one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from camwhisker.mechanics.whisker import (
    PHI_LINEAR_MAX_DEG,
    ElasticaError,
    WhiskerMechanics,
    beam_peg_response,
    solve_elastica,
)

__all__ = ["PegScene", "BoxScene", "CircleScene", "Sweep", "sweep", "SLIP_TOL_MM"]

# The contact point counts as slipping once it has moved this far along the
# object since first contact: a third of the paper's 3 mm GM precision.
SLIP_TOL_MM = 1.0


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


@dataclass(frozen=True)
class PegScene:
    """A point peg at height ``r_mm`` above the base line, at ``x_mm``.

    ``k_obj_n_per_mm`` is the peg's lateral spring; ``inf`` is a rigid peg.
    """

    r_mm: float
    x_mm: float = 0.0
    k_obj_n_per_mm: float = math.inf
    kind: str = field(default="peg", init=False)

    def first_contact_x(self, mech: WhiskerMechanics) -> float:
        return self.x_mm

    def profile_distance(self, x_mm, y_mm):
        return np.hypot(np.asarray(x_mm) - self.x_mm, np.asarray(y_mm) - self.r_mm)

    def outline(self):
        """Points (x_mm, y_mm) of the object's outline, for plots."""
        return np.array([self.x_mm]), np.array([self.r_mm])

    def constraint(self, mech: WhiskerMechanics):
        length = mech.length_mm

        def residuals(st, u):
            # The force on the peg is -F; its spring lets it give way along x.
            give = 0.0 if math.isinf(self.k_obj_n_per_mm) else -st["fx"] / self.k_obj_n_per_mm
            return (
                (st["xc"] - self.x_mm - give) / length,
                (st["yc"] - self.r_mm) / length,
                _wrap(u[2] - (st["bc"] + 0.5 * math.pi)),  # frictionless: force normal
            )

        return residuals

    def guess(self, mech: WhiskerMechanics, base_x_mm: float):
        phi, _, _ = beam_peg_response(mech, self.r_mm, base_x_mm - self.x_mm, self.k_obj_n_per_mm)
        phi = float(phi)
        return (phi, phi * mech.length_mm / self.r_mm, math.pi + phi, self.r_mm / mech.length_mm)


@dataclass(frozen=True)
class BoxScene(PegScene):
    """The lower-left corner (x_mm, r_mm) of a box that extends to +x and +y."""

    kind: str = field(default="box", init=False)

    def profile_distance(self, x_mm, y_mm):
        # Distance to the outline: the left face (x = x0, y >= y0) and the
        # bottom face (y = y0, x >= x0).
        x = np.asarray(x_mm, float) - self.x_mm
        y = np.asarray(y_mm, float) - self.r_mm
        d_left = np.hypot(x, np.minimum(y, 0.0))
        d_bottom = np.hypot(np.minimum(x, 0.0), y)
        return np.minimum(d_left, d_bottom)

    def outline(self, extent_mm: float = 60.0):
        return (np.array([self.x_mm, self.x_mm, self.x_mm + extent_mm]),
                np.array([self.r_mm + extent_mm, self.r_mm, self.r_mm]))


@dataclass(frozen=True)
class CircleScene:
    """A circle of ``radius_mm`` centred at (center_x_mm, center_y_mm)."""

    center_x_mm: float
    center_y_mm: float
    radius_mm: float
    kind: str = field(default="circle", init=False)

    def first_contact_x(self, mech: WhiskerMechanics) -> float:
        return self.center_x_mm - self.radius_mm

    def profile_distance(self, x_mm, y_mm):
        d = np.hypot(np.asarray(x_mm) - self.center_x_mm, np.asarray(y_mm) - self.center_y_mm)
        return np.abs(d - self.radius_mm)

    def outline(self, n: int = 181):
        a = np.linspace(0.0, 2.0 * np.pi, n)
        return (self.center_x_mm + self.radius_mm * np.cos(a),
                self.center_y_mm + self.radius_mm * np.sin(a))

    def constraint(self, mech: WhiskerMechanics):
        length = mech.length_mm
        cx, cy, rad = self.center_x_mm, self.center_y_mm, self.radius_mm

        def residuals(st, u):
            ex, ey = st["xc"] - cx, st["yc"] - cy
            return (
                (math.hypot(ex, ey) - rad) / length,
                (ex * math.cos(st["bc"]) + ey * math.sin(st["bc"])) / length,  # tangent
                _wrap(u[2] - (st["bc"] + 0.5 * math.pi)),
            )

        return residuals

    def guess(self, mech: WhiskerMechanics, base_x_mm: float):
        # A straight whisker from the base tangent to the circle's left side.
        dxc, dyc = self.center_x_mm - base_x_mm, self.center_y_mm
        d = math.hypot(dxc, dyc)
        beta = math.atan2(dyc, dxc) + math.asin(min(self.radius_mm / d, 1.0))
        phi = beta - 0.5 * math.pi
        t = math.sqrt(max(d * d - self.radius_mm**2, 1e-6))
        return (phi, max(phi, 1e-4) * mech.length_mm / t, beta + 0.5 * math.pi, t / mech.length_mm)


@dataclass(frozen=True)
class Sweep:
    """Quasi-static equilibria at a series of base positions (arrays, shape (N,))."""

    base_x_mm: np.ndarray
    in_contact: np.ndarray
    phi_deg: np.ndarray
    dz_mm: np.ndarray
    r_mm: np.ndarray
    s_contact_mm: np.ndarray
    contact_x_mm: np.ndarray
    contact_y_mm: np.ndarray
    force_n: np.ndarray
    slipping: np.ndarray
    elastica: np.ndarray


def sweep(scene, mech: WhiskerMechanics, base_x_mm, model: str = "auto") -> Sweep:
    """Solve the scene at each base position (mm, increasing, travel in +x).

    Parameters
    ----------
    scene : PegScene, BoxScene or CircleScene
    mech : WhiskerMechanics
    base_x_mm : array_like, shape (N,)
    model : {"auto", "beam", "elastica"}
        "auto" uses the closed-form beam for pegs while its phi stays below
        :data:`PHI_LINEAR_MAX_DEG` and the elastica elsewhere. The circle always
        needs the elastica (its contact point moves with the whisker's slope).

    Returns
    -------
    Sweep
        No contact: phi = dz = 0 and the contact fields NaN. A contact that
        leaves the whisker (s_c > l_w) ends the sweep's contact (NaN).
    """
    if model not in ("auto", "beam", "elastica"):
        raise ValueError(f"model must be 'auto', 'beam' or 'elastica', got {model!r}")
    xs = np.asarray(base_x_mm, dtype=float)
    n = xs.size
    out = {k: np.full(n, np.nan) for k in ("phi", "dz", "r", "s", "cx", "cy", "f")}
    in_contact = np.zeros(n, bool)
    slipping = np.zeros(n, bool)
    used_elastica = np.zeros(n, bool)
    x_first = scene.first_contact_x(mech)
    is_peg = isinstance(scene, PegScene)
    if model == "beam" and not is_peg:
        raise ValueError("the beam model only covers peg contact; use the elastica")
    constraint = scene.constraint(mech)
    prev = None
    first_point = None
    for i, xb in enumerate(xs):
        dx = xb - x_first
        if dx <= 0.0:
            out["phi"][i] = out["dz"][i] = 0.0
            prev = None
            continue
        if is_peg and model != "elastica":
            phi, dz, force = (float(v) for v in
                              beam_peg_response(mech, scene.r_mm, dx, scene.k_obj_n_per_mm))
            if model == "beam" or math.degrees(phi) < PHI_LINEAR_MAX_DEG:
                give = 0.0 if math.isinf(scene.k_obj_n_per_mm) else force / scene.k_obj_n_per_mm
                cx, cy = scene.x_mm + give, scene.r_mm
                out["phi"][i], out["dz"][i], out["f"][i] = math.degrees(phi), dz, force
                out["cx"][i], out["cy"][i] = cx, cy
                out["r"][i] = math.hypot(cx - xb, cy)
                out["s"][i] = scene.r_mm
                in_contact[i] = True
                if first_point is None:
                    first_point = (cx, cy)
                continue
        guess = prev.unknowns if prev is not None else scene.guess(mech, xb)
        try:
            sol = solve_elastica(mech, xb, constraint, guess)
        except ElasticaError:
            sol = solve_elastica(mech, xb, constraint, scene.guess(mech, xb))
        if sol.s_contact_mm > mech.length_mm or sol.force_n <= 0.0:
            out["phi"][i] = out["dz"][i] = np.nan
            prev = None
            continue
        prev = sol
        used_elastica[i] = True
        in_contact[i] = True
        out["phi"][i], out["dz"][i], out["f"][i] = sol.phi_deg, sol.dz_mm, sol.force_n
        out["cx"][i], out["cy"][i] = sol.contact_xy_mm
        out["r"][i], out["s"][i] = sol.r_mm, sol.s_contact_mm
        if first_point is None:
            first_point = sol.contact_xy_mm
    if first_point is not None and not is_peg:
        moved = np.hypot(out["cx"] - first_point[0], out["cy"] - first_point[1])
        slipping = np.where(in_contact, moved > SLIP_TOL_MM, False)
    return Sweep(
        base_x_mm=xs,
        in_contact=in_contact,
        phi_deg=out["phi"],
        dz_mm=out["dz"],
        r_mm=out["r"],
        s_contact_mm=out["s"],
        contact_x_mm=out["cx"],
        contact_y_mm=out["cy"],
        force_n=out["f"],
        slipping=slipping,
        elastica=used_elastica,
    )
