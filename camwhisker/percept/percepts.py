"""Shape percepts from surfels: wall, cylinder, corner or nothing, with intervals.

Each candidate model is fitted by robust least squares (Cauchy loss) to the
BIOTACT cost (Pearson et al., eqs. 3-7): believed contacts far from the
model's surface, free-space points (belief 0) inside the object, and surfels
whose direction is misaligned with the surface. The percept is the model with
the lowest Bayesian information criterion (the cost as a negative log
likelihood plus k ln n / 2): a model's extra parameters must pay for
themselves. "No object" charges every residual the cost of a contact
:data:`NONE_RESIDUAL` spreads from any surface.

Models (common frame, mm; the solid is on the side away from the free space):

- ``line`` (a wall): unit normal at angle t (toward free space), offset d:
  signed distance n . p - d. Reported as ``angle_deg`` (its direction, in
  [0, 180)) and ``distance_mm`` (from the origin).
- ``circle`` (a cylinder): centre (cx, cy), radius R.
- ``corner`` (two faces from an apex): apex (ax, ay), face direction a1 and
  the opening, face 2 at a1 - opening; the solid is the wedge between them,
  its opening held within :data:`CORNER_OPENING_DEG` (narrower, the two faces
  are one wall with a kink in its contact points), and a candidate only where the
  contacts nearest each face span :data:`CORNER_FACE_MIN_MM` of it (a face touched over
  a few millimetres is a bend in one face's contacts, not a second face).

A wall's contact slides at a phi its face's angle and friction set, as low as 1-3 deg,
where MF's r scatters by tens of mm; :func:`steep_turn_deg` gives the stage angle of a
next run over which the fitted line rises steeply.

Intervals are 95 % Wald intervals from the Jacobian at the solution (a
corner's with each contact's face held fixed, :func:`_frozen_jacobian`),
(J^T J)^-1 times the residuals' robust variance, inflated for the contacts'
correlation along a sweep (AR(1), :func:`ar1_inflation`; the campaign,
:mod:`camwhisker.bench.percepts`, measures how often they cover the truth).

References
----------
Pearson, M. J. et al. (2013). Simultaneous localisation and mapping on a
multi-degree of freedom biomimetic whiskered robot. ICRA. (BIOTACT surfels.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from camwhisker.percept.surfels import Surfels

__all__ = ["MODELS", "OBJECT_OF", "Fit", "Percept", "fit_model", "perceive", "object_of", "outline",
           "percept_record", "steep_turn_deg", "corner_face_spans", "RISE_DEG", "BLIND_TURN_DEG",
           "POINT_SIGMA_MM",
           "DIR_SIGMA_RAD", "NONE_RESIDUAL", "MIN_SURFELS", "ar1_inflation"]

MODELS = ("line", "circle", "corner")
#: What each model stands for.
OBJECT_OF = {"none": "no object", "line": "wall", "circle": "cylinder", "corner": "box corner"}
# Scale of a contact point's distance from the surface: the fused contact points
# scatter 0.1-0.3 mm about the profile but drift from it by a millimetre or more
# along a sweep: at 0.5 mm a corner or circle bent to that drift beat the line on
# half the walls of the tuning sweeps (seeds 0-39), at 1.5 mm on none.
POINT_SIGMA_MM = 1.5
# Scale of a chord direction's error: two points' ~0.1 mm scatter across a chord of a
# millimetre or two.
DIR_SIGMA_RAD = 0.3
# A contact this many scales from every surface is as likely as no object at all.
NONE_RESIDUAL = 3.0
# Fewer contacts than this cannot tell a shape: "no object".
MIN_SURFELS = 4
# The residuals' lag-1 autocorrelation is taken up to this (inflation 39 at most).
MAX_AUTOCORR = 0.95
# A box corner opens this far (deg): from a sharp wedge to a blunt edge.
CORNER_OPENING_DEG = (30.0, 150.0)
# A corner is a candidate only where the contacts nearest each face span this much of it
# (mm): the simulated corners' faces span 23-63 mm (tuning seeds 0-99), the stray second
# face of a slide past MF's table (the bundled box) 6.9 mm.
CORNER_FACE_MIN_MM = 15.0
# A wall's next run is turned so that the face rises this steeply: faces at 82-86 deg
# slide at phi 12-26 deg (friction 0.4-0.6), not the 2-18 deg of faces at 70-78, and MF's
# r is sharper there. Steeper, the approach's first base positions lie behind the line's
# extension below the face, and their free-space cost tilts the line.
RISE_DEG = 83.0
# Without a line the face slid at phi under ~3 deg, so it rises at 70-72 deg and friction
# is low: turned this way it rises at 82-84.
BLIND_TURN_DEG = -12.0
# Central-difference step of a corner's Jacobian, relative to each parameter (at least 1).
_JAC_STEP = 1e-6
# Two-sided 95 % normal quantile for the intervals.
Z95 = 1.959963984540054


@dataclass
class Fit:
    """One model's fit: parameters, intervals, cost and information criterion."""

    model: str
    params: dict
    intervals: dict
    cost: float
    bic: float
    n_residuals: int
    x: np.ndarray = field(repr=False, default=None)


@dataclass
class Percept:
    """The chosen model, every candidate's fit, the runner-up and the evidence ratio."""

    best: Fit
    fits: dict
    runner_up: str
    evidence_ratio: float
    n_surfels: int


def _rho(z):
    return np.log1p(z)  # scipy's "cauchy" loss, f_scale 1


# --- signed distance and tangent of each model --------------------------------------------


def _line_sd(x, p):
    t, d = x
    n = np.array([math.cos(t), math.sin(t)])
    return p @ n - d, np.broadcast_to(np.array([-n[1], n[0]]), p.shape)


def _circle_sd(x, p):
    cx, cy, r = x
    v = p - np.array([cx, cy])
    dist = np.hypot(v[:, 0], v[:, 1])
    u = v / np.maximum(dist, 1e-9)[:, None]
    return dist - abs(r), np.c_[-u[:, 1], u[:, 0]]


def _face_distances(x, p):
    """Each point's distance from a corner's face 1 and face 2 (half-lines from the apex)."""
    ax, ay, a1, opening = x
    v = p - np.array([ax, ay])
    dist = []
    for a in (a1, a1 - opening):
        u = np.array([math.cos(a), math.sin(a)])
        dist.append(np.hypot(*(v - np.clip(v @ u, 0.0, None)[:, None] * u).T))
    return dist


def _corner_sd(x, p, face2=None):
    """Signed distance to the nearer face, and that face's direction; ``face2`` (bool per
    point) fixes which face gives the direction instead (the distance stays the nearer's)."""
    ax, ay, a1, opening = x
    a2 = a1 - opening
    v = p - np.array([ax, ay])
    dist = _face_distances(x, p)
    best = np.minimum(*dist)
    if face2 is None:
        face2 = dist[1] < dist[0]
    tang = np.where(np.asarray(face2)[:, None], [math.cos(a2), math.sin(a2)],
                    [math.cos(a1), math.sin(a1)])
    # Inside the wedge (opening < 180 deg) when on the inner side of both faces.
    u1 = np.array([math.cos(a1), math.sin(a1)])
    u2 = np.array([math.cos(a2), math.sin(a2)])
    sgn = 1.0 if u1[0] * u2[1] - u1[1] * u2[0] > 0 else -1.0
    c1 = sgn * (u1[0] * v[:, 1] - u1[1] * v[:, 0])
    c2 = -sgn * (u2[0] * v[:, 1] - u2[1] * v[:, 0])
    inside = (c1 > 0) & (c2 > 0)
    return np.where(inside, -best, best), tang


_SD = {"line": _line_sd, "circle": _circle_sd, "corner": _corner_sd}


def _residuals(model, x, s: Surfels, face2=None):
    """Eqs. 3-7 as residuals in units of their scale: distance, misalignment, intrusion.

    A point's distance scale adds its error along the whisker (``s.spread``) as seen across
    the surface: an error along the surface moves a point without moving it off the surface
    (errors in variables; scaled by POINT_SIGMA_MM alone, the points' scatter along the
    whisker tilts a steep wall toward it). ``face2``: a corner's faces for the contacts'
    directions, fixed (:func:`_frozen_jacobian`)."""
    sd, tang = _SD[model](x, s.xy_mm) if face2 is None else _corner_sd(x, s.xy_mm, face2)
    across = tang[:, 0] * s.spread[:, 1] - tang[:, 1] * s.spread[:, 0]  # normal . spread
    res = [s.belief * sd / np.hypot(POINT_SIGMA_MM, across)]
    has = np.isfinite(s.dir[:, 0])
    cross = tang[has, 0] * s.dir[has, 1] - tang[has, 1] * s.dir[has, 0]
    res.append(s.belief[has] * cross / DIR_SIGMA_RAD)  # sin of the misalignment
    if s.free_xy_mm.size:
        fsd, _ = _SD[model](x, s.free_xy_mm)
        res.append(np.minimum(fsd, 0.0) / POINT_SIGMA_MM)  # free space inside the object
    return np.concatenate(res)


# --- starting points --------------------------------------------------------------------


def _line_start(s: Surfels):
    p = s.xy_mm
    c = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - c)
    n = vt[1]
    if s.free_xy_mm.size and np.mean((s.free_xy_mm - c) @ n) < 0:
        n = -n  # the normal points to free space
    t = math.atan2(n[1], n[0])
    return [np.array([t, float(c @ n)])]


def _circle_start(s: Surfels):
    """Kasa's algebraic circle, and circles through the extreme contacts in x at a range of
    radii (two short arcs from either side leave Kasa's fit near any radius)."""
    p = s.xy_mm
    a = np.c_[2 * p, np.ones(len(p))]
    b = (p ** 2).sum(axis=1)
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    starts = [np.array([sol[0], sol[1], math.sqrt(max(sol[2] + sol[0] ** 2 + sol[1] ** 2, 1.0))])]
    left, right = p[np.argmin(p[:, 0])], p[np.argmax(p[:, 0])]
    half = 0.5 * (right[0] - left[0])
    if half > 1.0:  # the sides' outermost contacts, where the tangent is along y
        starts.append(np.array([0.5 * (left[0] + right[0]), 0.5 * (left[1] + right[1]), half]))
    top = p[np.argmax(p[:, 1])]
    for r in (15.0, 30.0, 60.0):  # one side only: the circle beside its highest contact
        for side in (-1.0, 1.0):
            starts.append(np.array([top[0] + side * r, top[1], r]))
    return starts


def _corner_start(s: Surfels, n_apex: int = 12):
    """Apex candidates among the contacts, faces the mean directions of the two angular groups;
    and, for two tables, the corner of the lines fitted to each (a slide's scattered MF points
    can hide a face's direction from the groups, not from a fit that allows their spread)."""
    starts = _corner_starts_of(s.xy_mm, n_apex)
    tables = np.unique(s.table)
    if tables.size == 2:
        parts = [_contacts_of(s, s.table == t) for t in tables]
        fits = [fit_model("line", p) for p in parts if p.n >= MIN_SURFELS]
        if len(fits) == 2:
            starts += _corner_of_lines(fits, parts)
    return starts


def _contacts_of(s: Surfels, keep: np.ndarray) -> Surfels:
    """Some of the contacts, without free space (whose table is not kept: another run's base
    may lie beyond this face)."""
    return Surfels(s.xy_mm[keep], s.dir[keep], s.belief[keep], s.table[keep], np.empty((0, 2)),
                   s.spread[keep])


def _corner_of_lines(fits, parts):
    """Apex where two fitted lines cross; each face toward its table's contacts."""
    (t1, d1), (t2, d2) = (f.x for f in fits)
    a = np.array([[math.cos(t1), math.sin(t1)], [math.cos(t2), math.sin(t2)]])
    try:
        apex = np.linalg.solve(a, [d1, d2])
    except np.linalg.LinAlgError:
        return []
    faces = []
    for t, part in zip((t1, t2), parts, strict=True):
        u = np.array([-math.sin(t), math.cos(t)])
        if np.median((part.xy_mm - apex) @ u) < 0:
            u = -u
        faces.append(math.atan2(u[1], u[0]))
    return [_corner_vector(apex, *faces)]


def _corner_starts_of(p: np.ndarray, n_apex: int):
    """Up to ``n_apex`` contacts of ``p`` as apexes, each with the faces of its two groups."""
    starts = []
    for i in np.unique(np.linspace(0, len(p) - 1, min(n_apex, len(p))).astype(int)):
        v = np.delete(p, i, axis=0) - p[i]
        v = v[np.hypot(*v.T) > 1.0]
        if len(v) < 4:
            continue
        ang = np.sort(np.arctan2(v[:, 1], v[:, 0]))
        gaps = np.diff(np.r_[ang, ang[0] + 2 * math.pi])
        # The two largest gaps split the directions into the two faces.
        k1, k2 = np.sort(np.argsort(gaps)[-2:])
        g1 = ang[k1 + 1:k2 + 1]
        g2 = np.r_[ang[k2 + 1:], ang[:k1 + 1]]
        if len(g1) < 2 or len(g2) < 2:
            continue
        starts.append(_corner_vector(p[i], math.atan2(np.sin(g1).mean(), np.cos(g1).mean()),
                                     math.atan2(np.sin(g2).mean(), np.cos(g2).mean())))
    return starts


def _corner_vector(apex, a1: float, a2: float) -> np.ndarray:
    """The corner's parameters from its apex and two face directions (rad, either order)."""
    opening = (a1 - a2) % (2 * math.pi)
    if opening > math.pi:  # face 1 the counter-clockwise one
        a1, opening = a2, 2 * math.pi - opening
    lo, hi = np.radians(CORNER_OPENING_DEG)
    return np.array([apex[0], apex[1], a1, np.clip(opening, lo + 1e-3, hi - 1e-3)])


_STARTS = {"line": _line_start, "circle": _circle_start, "corner": _corner_start}
_K = {"line": 2, "circle": 3, "corner": 4}


def _public(model, x):
    """Reported parameters from the fitted vector (angles in degrees)."""
    if model == "line":
        t, d = x
        return {"angle_deg": math.degrees(t + math.pi / 2) % 180.0, "distance_mm": abs(d),
                "normal_deg": math.degrees(t) % 360.0, "offset_mm": d}
    if model == "circle":
        return {"center_x_mm": x[0], "center_y_mm": x[1], "radius_mm": abs(x[2])}
    return {"apex_x_mm": x[0], "apex_y_mm": x[1], "face1_deg": math.degrees(x[2]) % 360.0,
            "face2_deg": math.degrees(x[2] - x[3]) % 360.0, "opening_deg": math.degrees(x[3])}


def ar1_inflation(point_res: np.ndarray) -> float:
    """AR(1) variance inflation (1 + rho) / (1 - rho) of residuals in time order.

    Neighbouring contacts of a sweep err alike (the contact estimate drifts as
    the contact slides), so n of them carry fewer than n independent errors.
    """
    r = point_res - point_res.mean()
    if r.size < 3 or not np.any(r):
        return 1.0
    rho = float(np.clip(np.sum(r[1:] * r[:-1]) / np.sum(r * r), 0.0, MAX_AUTOCORR))
    return (1.0 + rho) / (1.0 - rho)


def _frozen_jacobian(x, s: Surfels) -> np.ndarray:
    """A corner's Jacobian by central differences, each contact's face held as at ``x``.

    A contact as far from both faces switches face, and its direction term jumps, as the
    apex moves; a difference across that jump is no derivative (it put ~1e6 in J and a zero
    width in the apex's interval), and the intervals are for the faces as assigned."""
    dist = _face_distances(x, s.xy_mm)
    face2 = dist[1] < dist[0]
    cols = []
    for i in range(x.size):
        h = np.zeros(x.size)
        h[i] = _JAC_STEP * max(1.0, abs(x[i]))
        cols.append((_residuals("corner", x + h, s, face2) - _residuals("corner", x - h, s, face2))
                    / (2.0 * h[i]))
    return np.column_stack(cols)


def _intervals(model, x, jac, fun, k, n_points, m):
    """95 % Wald intervals of the reported parameters (NaN where J^T J is singular).

    The spread comes from the ``m`` contact and direction residuals; free-space
    residuals (zero unless the model swallows the base) would only dilute it.
    """
    sigma2 = float(np.sum(_rho(fun[:m] ** 2))) / max(m - k, 1) * ar1_inflation(fun[:n_points])
    try:
        cov = np.linalg.inv(jac.T @ jac) * sigma2
    except np.linalg.LinAlgError:
        cov = np.full((k, k), np.nan)
    half = Z95 * np.sqrt(np.clip(np.diag(cov), 0.0, None))
    names = list(_public(model, x))
    if model == "line":
        widths = [math.degrees(half[0]), half[1], math.degrees(half[0]), half[1]]
    elif model == "circle":
        widths = list(half)
    else:
        face2 = math.degrees(math.sqrt(max(cov[2, 2] + cov[3, 3] - 2 * cov[2, 3], 0.0)))
        widths = [half[0], half[1], math.degrees(half[2]), Z95 * face2, math.degrees(half[3])]
    pub = _public(model, x)
    return {name: [pub[name] - w, pub[name] + w] for name, w in zip(names, widths, strict=True)}


def corner_face_spans(x, p) -> tuple[float, float]:
    """The extent (mm) along each face of a corner ``x`` of the points ``p`` nearest it."""
    ax, ay, a1, opening = x
    d1, d2 = _face_distances(x, p)
    spans = []
    for near, a in ((d1 <= d2, a1), (d2 < d1, a1 - opening)):
        t = (p[near] - [ax, ay]) @ [math.cos(a), math.sin(a)]
        spans.append(float(np.ptp(t)) if t.size else 0.0)
    return spans[0], spans[1]


def fit_model(model: str, s: Surfels) -> Fit | None:
    """Robust least-squares fit of one model to the surfels; None without a starting point."""
    if model not in _SD:
        raise ValueError(f"unknown model {model!r} (known: {', '.join(MODELS)})")
    best = None
    bounds = (-np.inf, np.inf)
    if model == "corner":
        lo, hi = np.radians(CORNER_OPENING_DEG)
        bounds = ([-np.inf, -np.inf, -np.inf, lo], [np.inf, np.inf, np.inf, hi])
    for x0 in _STARTS[model](s):
        res = least_squares(lambda x: _residuals(model, x, s), x0, loss="cauchy", f_scale=1.0,
                            bounds=bounds)
        if best is None or res.cost < best.cost:
            best = res
    if best is None:
        return None
    k = _K[model]
    m = _n_contact_residuals(s)
    cost = float(np.sum(_rho(best.fun ** 2)))
    jac = _frozen_jacobian(best.x, s) if model == "corner" else best.jac
    intervals = _intervals(model, best.x, jac, best.fun, k, s.n, m)
    return Fit(model, _public(model, best.x), intervals, cost, cost + k * math.log(m), m, best.x)


def _n_contact_residuals(s: Surfels) -> int:
    """Contacts plus those with a direction: the data the information criterion counts."""
    return s.n + int(np.isfinite(s.dir[:, 0]).sum())


def _none_fit(s: Surfels) -> Fit:
    """No object: every contact and direction unexplained, nothing inside anything."""
    m = _n_contact_residuals(s)
    cost = m * float(_rho(NONE_RESIDUAL ** 2))
    return Fit("none", {}, {}, cost, cost, m)


def perceive(s: Surfels, models=MODELS) -> Percept:
    """Fit every model and choose by BIC; "none" with fewer than :data:`MIN_SURFELS` contacts."""
    fits = {"none": _none_fit(s)}
    if s.n >= MIN_SURFELS:
        for model in models:
            f = fit_model(model, s)
            # Two faces where only one was touched would invent the other.
            if f is None or (model == "corner"
                             and min(corner_face_spans(f.x, s.xy_mm)) < CORNER_FACE_MIN_MM):
                continue
            fits[model] = f
    ranked = sorted(fits.values(), key=lambda f: f.bic)
    best = ranked[0]
    runner = ranked[1] if len(ranked) > 1 else None
    ratio = math.exp(min((runner.bic - best.bic) / 2.0, 700.0)) if runner else math.inf
    return Percept(best, fits, runner.model if runner else "", ratio, s.n)


def object_of(p: Percept) -> str:
    """What the percept says is there: its model's object, or, where "none" comes from one to
    :data:`MIN_SURFELS` - 1 contacts, that they are too few to tell a shape."""
    if p.best.model == "none" and 0 < p.n_surfels < MIN_SURFELS:
        return f"too few contacts to tell a shape ({p.n_surfels})"
    return OBJECT_OF[p.best.model]


def outline(fit: Fit, near_xy=None, n: int = 181):
    """Points (x_mm, y_mm) of a fitted model's outline, for plots (empty for "none").

    Lines and corner faces are drawn over the extent of ``near_xy`` (shape (N, 2), the
    surfels) and 10 mm beyond; 60 mm without them.
    """
    x = fit.x
    pts = np.empty((0, 2)) if near_xy is None else np.asarray(near_xy, float).reshape(-1, 2)
    if fit.model == "circle":
        a = np.linspace(0.0, 2 * math.pi, n)
        return x[0] + abs(x[2]) * np.cos(a), x[1] + abs(x[2]) * np.sin(a)
    if fit.model == "line":
        t, d = x
        nrm = np.array([math.cos(t), math.sin(t)])
        tan = np.array([-nrm[1], nrm[0]])
        s = pts @ tan if len(pts) else np.array([-50.0, 50.0])
        s = np.array([s.min() - 10.0, s.max() + 10.0])
        return d * nrm[0] + s * tan[0], d * nrm[1] + s * tan[1]
    if fit.model == "corner":
        ax, ay, a1, opening = x
        a2 = a1 - opening
        reach = float(np.hypot(*(pts - [ax, ay]).T).max()) + 10.0 if len(pts) else 60.0
        return (np.array([ax + reach * math.cos(a1), ax, ax + reach * math.cos(a2)]),
                np.array([ay + reach * math.sin(a1), ay, ay + reach * math.sin(a2)]))
    return np.array([]), np.array([])


def steep_turn_deg(percept: Percept, rise_deg: float = RISE_DEG) -> float:
    """The stage angle (deg, a pose's in the common frame) of a run over which the line of
    ``percept`` rises at ``rise_deg`` from the travel direction; :data:`BLIND_TURN_DEG`
    where no line was fitted."""
    line = percept.fits.get("line")
    if line is None:
        return BLIND_TURN_DEG
    return (line.params["angle_deg"] - rise_deg + 90.0) % 180.0 - 90.0


def percept_record(p: Percept) -> dict:
    """The percept as plain data: chosen model, parameters with 95 % intervals, runner-up,
    evidence ratio (exp of half the BIC difference), every candidate's BIC and, for a wall,
    the stage angle of a steep next run (:func:`steep_turn_deg`)."""
    return {
        "model": p.best.model,
        "object": object_of(p),
        "params": p.best.params,
        "intervals_95": p.best.intervals,
        "runner_up": p.runner_up,
        "evidence_ratio": p.evidence_ratio,
        "n_surfels": p.n_surfels,
        "next_run_angle_deg": steep_turn_deg(p) if p.best.model == "line" else None,
        "candidates": {m: {"bic": f.bic, "cost": f.cost, "n_residuals": f.n_residuals,
                           "params": f.params} for m, f in p.fits.items()},
    }
