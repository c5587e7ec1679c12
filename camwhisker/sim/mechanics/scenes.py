"""Scenes for the stage experiments and their quasi-static sweeps.

A scene is what the whisker touches while its base travels along +x:

- :class:`PegScene`: a point peg at (x_mm, r_mm), rigid or on a spring (the
  compliant "pipe cleaner" of the paper). The object point stays fixed (or
  moves with its spring), so the GM assumption holds for the rigid peg.
- :class:`BoxScene`: a tilted box; the whisker sticks at its lowest corner
  (Coulomb friction), then slides up the face next to it with phi steady, so
  the GM overestimates r more and more (the paper's Fig. 9 failure).
- :class:`CircleScene`: a circular cross-section (a water bottle); the
  whisker's side stays tangent to it and the point of tangency slides down the
  bottle as the whisker leans back (frictionless, like the peg).

See :class:`_FrictionContact` for the box's stick / slip model and its limits.

:func:`sweep` solves one equilibrium per base position, continuing each solve
from the last one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from camwhisker.sim.mechanics.whisker import (
    PHI_LINEAR_MAX_DEG,
    ElasticaError,
    WhiskerMechanics,
    beam_peg_response,
    solve_elastica,
)

__all__ = ["PegScene", "BoxScene", "CircleScene", "Sweep", "sweep", "SLIP_TOL_MM", "wrap_angle"]

# The contact point counts as slipping once it has moved this far along the
# object since first contact: a third of the paper's 3 mm GM precision.
SLIP_TOL_MM = 1.0
# Search step along the profile for the end of an unstable slide, and the
# bisection that follows: 0.5 mm / 2^10 is far below the sensor's resolution.
SLIP_SEARCH_MM = 0.5
SLIP_BISECT_ITERATIONS = 10


def wrap_angle(angle: float) -> float:
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
                wrap_angle(u[2] - (st["bc"] + 0.5 * math.pi)),  # frictionless: force normal
            )

        return residuals

    def guess(self, mech: WhiskerMechanics, base_x_mm: float):
        phi, _, _ = beam_peg_response(mech, self.r_mm, base_x_mm - self.x_mm, self.k_obj_n_per_mm)
        phi = float(phi)
        return (phi, phi * mech.length_mm / self.r_mm, math.pi + phi, self.r_mm / mech.length_mm)


def _polyline_distance(x_mm, y_mm, xs, ys):
    """Distance of points to a closed polyline through (xs, ys) (vertices, shape (V,))."""
    x = np.asarray(x_mm, float)[..., None]
    y = np.asarray(y_mm, float)[..., None]
    ax, ay = np.asarray(xs, float), np.asarray(ys, float)
    bx, by = np.roll(ax, -1), np.roll(ay, -1)
    ex, ey = bx - ax, by - ay
    t = np.clip(((x - ax) * ex + (y - ay) * ey) / (ex * ex + ey * ey), 0.0, 1.0)
    return np.min(np.hypot(x - ax - t * ex, y - ay - t * ey), axis=-1)


class _FrictionContact:
    """Point contact with Coulomb friction on a 2D profile (the box's corner and face).

    The contact is a point load that a point of the whisker puts on the object's
    profile, normal to the whisker (the whisker slides freely along its own
    length, as on a peg). With n_out the profile's outward normal and t the
    direction in which the contact would slide (both at the contact point), the
    load on the whisker is F = N n_out + T t.

    - *Stick* while -T <= mu N (the load on the object lies in the friction
      cone): the object point stays where it is, the whisker pivots on it like
      on a rigid peg, and the GM's fixed-contact assumption holds.
    - *Slip* once the stuck load would leave the cone: the contact point slides
      along the profile with the load on the cone's edge, F || n_out - mu t.
      Together with "F normal to the whisker" this fixes the whisker's slope at
      the contact relative to the profile, so phi stops growing (it stabilises
      or falls) while the base keeps travelling; the GM then overestimates r.

    Modelling choice: the profile is taken as the locus of contact points; the
    whisker's body away from the contact is not checked against the object (it
    leans away from the face it slides up). A smooth convex object is a
    different contact: see :class:`CircleScene`.
    """

    mu: float

    def frame_at(self, x_mm: float, y_mm: float):
        """(n_out, t_slide) unit vectors at the profile point nearest (x, y)."""
        raise NotImplementedError

    def signed_distance(self, x_mm: float, y_mm: float) -> float:
        raise NotImplementedError

    def on_profile(self, x_mm: float, y_mm: float) -> bool:
        """Whether (x, y) lies on the part of the profile that the model covers."""
        raise NotImplementedError

    def arc_at(self, x_mm: float, y_mm: float) -> float:
        """Position (mm) along the profile, increasing in the sliding direction."""
        raise NotImplementedError

    def point_at(self, arc_mm: float):
        raise NotImplementedError

    def cone_ratio(self, force_angle_rad: float, x_mm: float, y_mm: float) -> float:
        """-T / N of a load on the whisker at angle alpha (inf when it does not push)."""
        (nx, ny), (tx, ty) = self.frame_at(x_mm, y_mm)
        fx, fy = math.cos(force_angle_rad), math.sin(force_angle_rad)
        normal = fx * nx + fy * ny
        if normal <= 0.0:
            return math.inf
        return -(fx * tx + fy * ty) / normal

    def slip_constraint(self, mech: WhiskerMechanics):
        length = mech.length_mm
        mu = self.mu

        def residuals(st, u):
            (nx, ny), (tx, ty) = self.frame_at(st["xc"], st["yc"])
            edge = math.atan2(ny - mu * ty, nx - mu * tx)  # load on the cone's edge
            return (
                self.signed_distance(st["xc"], st["yc"]) / length,
                wrap_angle(u[2] - (st["bc"] + 0.5 * math.pi)),  # normal to the whisker
                wrap_angle(u[2] - edge),
            )

        return residuals


@dataclass(frozen=True)
class BoxScene(_FrictionContact):
    """A box, tilted so that its face next to the lowest corner rises at ``face_angle_deg``.

    The whisker (travelling in +x) first meets the box at the corner
    (corner_x_mm, corner_y_mm), where it sticks; once the load leaves the
    friction cone of the face it slides up that face (an L-shaped cross-section
    seen edge-on, like the paper's box). Sides: ``face_length_mm`` along the
    face, ``depth_mm`` along the bottom.
    """

    corner_x_mm: float
    corner_y_mm: float
    face_angle_deg: float = 75.0
    mu: float = 0.4
    face_length_mm: float = 60.0
    depth_mm: float = 40.0
    kind: str = field(default="box", init=False)

    @property
    def _d(self):
        a = math.radians(self.face_angle_deg)
        return math.cos(a), math.sin(a)

    def first_contact_x(self, mech: WhiskerMechanics) -> float:
        return self.corner_x_mm

    def first_point(self):
        return self.corner_x_mm, self.corner_y_mm

    def frame_at(self, x_mm, y_mm):
        dx, dy = self._d
        return (-dy, dx), (dx, dy)

    def signed_distance(self, x_mm, y_mm):
        (nx, ny), _ = self.frame_at(x_mm, y_mm)
        return (x_mm - self.corner_x_mm) * nx + (y_mm - self.corner_y_mm) * ny

    def arc_at(self, x_mm, y_mm) -> float:
        """Distance (mm) along the face from the corner to the foot of (x, y)."""
        dx, dy = self._d
        return (x_mm - self.corner_x_mm) * dx + (y_mm - self.corner_y_mm) * dy

    def point_at(self, arc_mm: float):
        dx, dy = self._d
        return self.corner_x_mm + arc_mm * dx, self.corner_y_mm + arc_mm * dy

    def on_profile(self, x_mm, y_mm):
        return -1e-6 <= self.arc_at(x_mm, y_mm) <= self.face_length_mm

    def outline(self):
        """Closed outline (x_mm, y_mm) of the box: corner, up the face, across, down."""
        dx, dy = self._d
        ex, ey = dy, -dx  # along the bottom, into the box
        c = np.array([self.corner_x_mm, self.corner_y_mm])
        pts = [c, c + self.face_length_mm * np.array([dx, dy]),
               c + self.face_length_mm * np.array([dx, dy]) + self.depth_mm * np.array([ex, ey]),
               c + self.depth_mm * np.array([ex, ey]), c]
        pts = np.array(pts)
        return pts[:, 0], pts[:, 1]

    def profile_distance(self, x_mm, y_mm):
        ox, oy = self.outline()
        return _polyline_distance(x_mm, y_mm, ox[:-1], oy[:-1])


@dataclass(frozen=True)
class CircleScene:
    """A circle of ``radius_mm`` centred at (center_x_mm, center_y_mm): a water bottle.

    The whisker's side touches the bottle: at the contact the whisker is tangent
    to the circle and the load is along their common normal (frictionless, as
    on a peg). The whisker first meets the bottle at its leftmost point; as the
    base travels on (+x) and the whisker leans back, the point of tangency
    slides down the bottle's near side toward the base, so r falls while the
    GM, which assumes a fixed object point, keeps reporting about the first one
    (the slip of the paper's Fig. 9). A smooth convex profile has no stuck
    stretch: in the plane a whisker pinned at one point of the circle while
    leaning would cut into it.
    """

    center_x_mm: float
    center_y_mm: float
    radius_mm: float
    kind: str = field(default="circle", init=False)

    def first_contact_x(self, mech: WhiskerMechanics) -> float:
        return self.center_x_mm - self.radius_mm

    def mirrored(self) -> CircleScene:
        """The same bottle seen with x -> -x (for a stage travelling in -x)."""
        return CircleScene(-self.center_x_mm, self.center_y_mm, self.radius_mm)

    def constraint(self, mech: WhiskerMechanics):
        length = mech.length_mm
        cx, cy, radius = self.center_x_mm, self.center_y_mm, self.radius_mm

        def residuals(st, u):
            ax, ay = st["xc"] - cx, st["yc"] - cy
            normal = st["bc"] + 0.5 * math.pi  # the whisker's normal, toward -x at rest
            return (
                (math.hypot(ax, ay) - radius) / length,  # on the circle
                wrap_angle(math.atan2(ay, ax) - normal),  # tangent to it there
                wrap_angle(u[2] - normal),  # frictionless: load along the normal
            )

        return residuals

    def guess(self, mech: WhiskerMechanics, base_x_mm: float):
        return PegScene(self.center_y_mm, self.first_contact_x(mech)).guess(mech, base_x_mm)

    def profile_distance(self, x_mm, y_mm):
        d = np.hypot(np.asarray(x_mm) - self.center_x_mm, np.asarray(y_mm) - self.center_y_mm)
        return np.abs(d - self.radius_mm)

    def outline(self, n: int = 181):
        a = np.linspace(0.0, 2.0 * np.pi, n)
        return (self.center_x_mm + self.radius_mm * np.cos(a),
                self.center_y_mm + self.radius_mm * np.sin(a))


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
    sliding: np.ndarray | None = None  # friction scenes: the contact slid at this step


def _solve(mech, xb, constraint, guesses):
    """Solve from the first guess that converges; re-raise the last failure."""
    err = None
    for g in guesses:
        if g is None:
            continue
        try:
            return solve_elastica(mech, xb, constraint, g)
        except ElasticaError as exc:
            err = exc
    raise err


def _stuck(scene, mech, xb, point, guesses):
    """The whisker held at an object point (a rigid peg there) and its -T / N ratio."""
    peg = PegScene(point[1], point[0])
    try:
        sol = _solve(mech, xb, peg.constraint(mech), (*guesses, peg.guess(mech, xb)))
    except ElasticaError:
        return None, math.inf
    return sol, scene.cone_ratio(sol.unknowns[2], *point)


def _stick_or_slip(scene, mech, xb, anchor, slip_c, prev):
    """Equilibrium at base position xb from the contact's current object point.

    Returns (solution or None if contact is lost, slid). Slip is solved with the
    load on the cone's edge; a solution that moved against the sliding
    direction (or none) means the cone-edge state is unstable there, and the
    contact is followed along the profile in steps of :data:`SLIP_SEARCH_MM`
    to the first point where it can stick again (the quasi-static end of a
    fast slide); with none on the profile, contact is lost (the whisker snaps
    off the object).
    """
    guess = prev.unknowns if prev is not None else None
    sol, ratio = _stuck(scene, mech, xb, anchor, (guess,))
    if sol is not None and ratio <= scene.mu:
        return sol, False
    q0 = scene.arc_at(*anchor)
    try:
        slip = _solve(mech, xb, slip_c, (sol.unknowns if sol else None, guess))
        if scene.arc_at(*slip.contact_xy_mm) >= q0 - 1e-6:
            return slip, True
    except ElasticaError:
        pass
    # Follow the profile to where the load is back inside the cone.
    q_prev, last = q0, sol
    q = q0 + SLIP_SEARCH_MM
    while scene.on_profile(*scene.point_at(q)):
        cand, r = _stuck(scene, mech, xb, scene.point_at(q), (last.unknowns if last else None,))
        if cand is None:
            return None, True
        if r <= scene.mu:
            lo, hi, best = q_prev, q, cand
            for _ in range(SLIP_BISECT_ITERATIONS):
                mid = 0.5 * (lo + hi)
                c2, r2 = _stuck(scene, mech, xb, scene.point_at(mid), (best.unknowns,))
                if c2 is not None and r2 <= scene.mu:
                    hi, best = mid, c2
                else:
                    lo = mid
            return best, True
        q_prev, last = q, cand
        q += SLIP_SEARCH_MM
    return None, True


_COLUMNS = ("phi", "dz", "r", "s", "cx", "cy", "f")


def _columns(n: int) -> dict:
    """The sweep's per-step columns, NaN until solved."""
    return {k: np.full(n, np.nan) for k in _COLUMNS}


def _row(sol) -> dict:
    """One step's columns from an elastica solution."""
    cx, cy = sol.contact_xy_mm
    return {"phi": sol.phi_deg, "dz": sol.dz_mm, "f": sol.force_n, "cx": cx, "cy": cy,
            "r": sol.r_mm, "s": sol.s_contact_mm}  # fmt: skip


def _put(out: dict, i: int, row: dict) -> None:
    for k, v in row.items():
        out[k][i] = v


def _slipping(out: dict, in_contact: np.ndarray, first_point) -> np.ndarray:
    """Steps whose contact point lies more than SLIP_TOL_MM from the first one."""
    moved = np.hypot(out["cx"] - first_point[0], out["cy"] - first_point[1])
    return np.where(in_contact, moved > SLIP_TOL_MM, False)


def _as_sweep(xs, out, in_contact, slipping, elastica, sliding=None) -> Sweep:
    return Sweep(
        base_x_mm=xs, in_contact=in_contact, phi_deg=out["phi"], dz_mm=out["dz"],
        r_mm=out["r"], s_contact_mm=out["s"], contact_x_mm=out["cx"], contact_y_mm=out["cy"],
        force_n=out["f"], slipping=slipping, elastica=elastica, sliding=sliding,
    )  # fmt: skip


def _sweep_friction(scene, mech: WhiskerMechanics, xs: np.ndarray) -> Sweep:
    """Quasi-static stick / slip sweep of a friction scene (see :class:`_FrictionContact`).

    At each base position the contact is first held at its current object
    point (stick, a rigid peg there). If that load lies outside the friction
    cone, the contact slides instead (load on the cone's edge). Contact ends
    (NaN from there on) when it leaves the modelled profile or the whisker, or
    the load stops pushing.
    """
    n = xs.size
    out = _columns(n)
    in_contact = np.zeros(n, bool)
    sliding = np.zeros(n, bool)
    x_first = scene.first_contact_x(mech)
    first = scene.first_point()
    anchor = first
    slip_c = scene.slip_constraint(mech)
    prev = None
    lost = False
    for i, xb in enumerate(xs):
        if xb - x_first <= 0.0:
            out["phi"][i] = out["dz"][i] = 0.0
            continue
        if lost:
            continue
        sol, slid = _stick_or_slip(scene, mech, xb, anchor, slip_c, prev)
        if (sol is None or sol.s_contact_mm > mech.length_mm or sol.force_n <= 0.0
                or not scene.on_profile(*sol.contact_xy_mm)):
            out["phi"][i] = out["dz"][i] = np.nan
            lost = True
            continue
        prev = sol
        anchor = sol.contact_xy_mm
        in_contact[i] = True
        sliding[i] = slid
        _put(out, i, _row(sol))
    slipping = _slipping(out, in_contact, first)
    return _as_sweep(xs, out, in_contact, slipping, in_contact.copy(), sliding)


def _beam_row(scene: PegScene, mech: WhiskerMechanics, xb: float, dx: float, model: str):
    """The closed-form beam's columns at base xb, or None where the elastica is needed."""
    phi, dz, force = (float(v) for v in
                      beam_peg_response(mech, scene.r_mm, dx, scene.k_obj_n_per_mm))  # fmt: skip
    if not (model == "beam" or math.degrees(phi) < PHI_LINEAR_MAX_DEG):
        return None
    give = 0.0 if math.isinf(scene.k_obj_n_per_mm) else force / scene.k_obj_n_per_mm
    cx, cy = scene.x_mm + give, scene.r_mm
    return {"phi": math.degrees(phi), "dz": dz, "f": force, "cx": cx, "cy": cy,
            "r": math.hypot(cx - xb, cy), "s": scene.r_mm}  # fmt: skip


def _elastica_step(scene, mech: WhiskerMechanics, xb: float, constraint, prev):
    """The elastica at base xb, continued from ``prev`` (else from the scene's guess);
    None where the contact leaves the whisker or stops pushing."""
    guess = prev.unknowns if prev is not None else scene.guess(mech, xb)
    try:
        sol = solve_elastica(mech, xb, constraint, guess)
    except ElasticaError:
        sol = solve_elastica(mech, xb, constraint, scene.guess(mech, xb))
    if sol.s_contact_mm > mech.length_mm or sol.force_n <= 0.0:
        return None
    return sol


def _sweep_smooth(scene, mech: WhiskerMechanics, xs: np.ndarray, model: str) -> Sweep:
    """Sweep of a peg or a circle: the beam where ``model`` allows it, else the elastica."""
    n = xs.size
    out = _columns(n)
    in_contact = np.zeros(n, bool)
    used_elastica = np.zeros(n, bool)
    x_first = scene.first_contact_x(mech)
    is_peg = isinstance(scene, PegScene)
    constraint = scene.constraint(mech)
    prev = None
    first_point = None
    for i, xb in enumerate(xs):
        dx = xb - x_first
        if dx <= 0.0:
            out["phi"][i] = out["dz"][i] = 0.0
            prev = None
            continue
        row = _beam_row(scene, mech, xb, dx, model) if is_peg and model != "elastica" else None
        if row is None:
            prev = _elastica_step(scene, mech, xb, constraint, prev)
            if prev is None:
                out["phi"][i] = out["dz"][i] = np.nan
                continue
            used_elastica[i] = True
            row = _row(prev)
        _put(out, i, row)
        in_contact[i] = True
        if first_point is None:
            first_point = (row["cx"], row["cy"])
    slipping = np.zeros(n, bool)
    if first_point is not None and not is_peg:
        slipping = _slipping(out, in_contact, first_point)
    return _as_sweep(xs, out, in_contact, slipping, used_elastica)


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
    if model == "beam" and not isinstance(scene, PegScene):
        raise ValueError("the beam model only covers peg contact; use the elastica")
    if isinstance(scene, _FrictionContact):
        return _sweep_friction(scene, mech, xs)
    return _sweep_smooth(scene, mech, xs, model)
