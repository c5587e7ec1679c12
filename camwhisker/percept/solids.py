"""Objects in 3-D from contacts placed in W: plane, sphere, cylinder or none, with intervals.

The 3-D form of :mod:`camwhisker.percept.percepts` (docs/sensor.md section 9). Surfels come
from contact tables with the world columns (``camwhisker contact --pose``): a point on the
surface, the surface normal's estimate across the shaft (toward psi) and, where the table
has it, the shaft's rest direction. Each model is fitted by robust least squares (Cauchy
loss) to seed 000's cost (eqs. 3-6) less its free-space term: contacts far from the surface
and normals that disagree with the surface's, each normal on its own scale
(:func:`_normal_sigma`: tight for a tap, loose where the base dragged the contact
sideways); the model with the lowest BIC is the percept, "none" charging each residual
:data:`NONE_RESIDUAL` scales. The free-space term is left out: the base, the only free
space a table holds, passes behind a finite wall's plane while it touches the wall's edge
(it turned walls into cylinders), and the measured normals already say which side is
outside.

A measured normal lies across the shaft: the surface's own normal less its component along
the shaft (the contact force's component along the shaft does not bend the whisker). So a
model's normal is compared with it in the plane across the shaft, where the table gives
the shaft's direction.

Models (W, mm; each normal points out of the object):

- ``plane``: unit normal n and distance d, n . p = d;
- ``sphere``: centre c and radius R;
- ``cylinder``: a point c on its axis, the axis u (unit) and radius R; c is the axis's
  point nearest the contacts' centroid.

Intervals are 95 % Wald intervals: (J^T J)^-1 times the residuals' robust variance,
inflated for the contacts' correlation along a sweep, carried to the reported
parameters by their Jacobian (the delta method); with contacts from two tables or more,
widened by the leave-one-table-out jackknife (Student's t): a run's own bias (MF's along
the shaft in a slide) is shared by all its contacts and shows only between runs
(BENCHMARKS.md, objects in 3-D).

References
----------
Pearson, M. J. et al. (seed paper 000), eqs. 3-7: surfels, the percept cost, model choice.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import t as student_t

from camwhisker.files.tables import TableError, read_columns
from camwhisker.percept.percepts import (
    DIR_SIGMA_RAD,
    NONE_RESIDUAL,
    POINT_SIGMA_MM,
    RISE_DEG,
    Z95,
    Fit,
    Percept,
    ar1_inflation,
)

__all__ = ["MODELS", "Surfels3", "surfels_from_tables", "read_surfels3",
           "fit_solid", "perceive_solid", "next_plane_run", "next_touch", "solid_record",
           "MIN_SURFELS", "REQUIRED_COLUMNS", "OPTIONAL_COLUMNS"]  # fmt: skip

MODELS = ("plane", "sphere", "cylinder")
#: Fewer contacts than this cannot tell a shape in 3-D: "none".
MIN_SURFELS = 6
#: Scale of a measured normal's error (rad) where the base moved in the plane of its shaft
#: and the normal (a tap, a sweep in one plane): friction then bends the whisker in that
#: plane too, and theta's run mean holds the normal to 0.01-0.03 deg; the scale is a
#: sensor's mount known to about a degree (a tighter one loses spheres to cylinders there).
NORMAL_SIGMA_RAD = 0.04
#: A base moving across that plane drags the contact sideways: Coulomb friction turns the
#: bending direction by up to about this times the travel's part across the plane.
LATERAL_MU = 0.6
#: The contact side's error along the surface normal (mm) that every table of one
#: calibration shares, so that no number of them averages it away: no length's 95 %
#: interval is narrower than 1.96 times it. Lifted cylinders of tuning seeds 1-28: the
#: centres 0.08-0.11 mm off, the radii 0.01-0.02 mm short, with intervals of 0.004-0.03.
SYSTEMATIC_MM = 0.06
# A model normal within this of the shaft (its part across the shaft under sin 6 deg) says
# nothing about the measured one, which lies across the shaft.
_ACROSS_MIN = 0.1
# Scale (mm) of the cylinder's gauge residual: it only pins c along the axis.
_GAUGE_MM = 1.0
# Starting radii (mm) for spheres and cylinders, from a fingertip to a bin.
_START_RADII_MM = (10.0, 30.0, 100.0, 300.0)
# Step of the reported parameters' numeric Jacobian.
_STEP = 1e-6
# Candidate touches on a sphere (a Fibonacci lattice) and, on a cylinder, around its axis by
# along it: a touch every 3-4 deg of a sphere, every 15 deg of a cylinder's round.
_SPHERE_CANDIDATES = 2000
_ROUND_CANDIDATES, _AXIAL_CANDIDATES = 24, 21
# A next touch along a cylinder's axis stays within the contacts' span plus this many radii:
# further out the axis's extent is unknown.
_AXIAL_REACH_RADII = 0.5

_WORLD = ("px_mm", "py_mm", "pz_mm")
_NORMAL = ("nx", "ny", "nz")
_SHAFT = ("ax", "ay", "az")
_BASE = ("bx_mm", "by_mm", "bz_mm")
#: What a contact table in space must have (docs/sensor.md section 9), and uses if present.
REQUIRED_COLUMNS = _WORLD + _NORMAL
OPTIONAL_COLUMNS = _SHAFT + _BASE


@dataclass(frozen=True)
class Surfels3:
    """Contacts in W: ``p_mm`` (N, 3), ``normal`` (N, 3) unit or NaN, ``shaft`` (N, 3) unit
    or NaN, ``table`` (N,), ``travel`` (N, 3): the unit direction its table's base moved
    in, NaN where the table has no base columns."""

    p_mm: np.ndarray
    normal: np.ndarray
    shaft: np.ndarray
    table: np.ndarray
    travel: np.ndarray | None = None

    @property
    def n(self) -> int:
        return int(self.p_mm.shape[0])


def _stack(cols: dict, names) -> np.ndarray:
    return np.column_stack([np.asarray(cols[c], float) for c in names])


def surfels_from_tables(tables: list[dict], sources: list[str] | None = None) -> Surfels3:
    """Surfels of contact tables' columns (as read by :func:`read_columns`): one per distinct
    contact point (a pause's estimate repeated on its frames counts once)."""
    parts = []
    for i, cols in enumerate(tables):
        name = sources[i] if sources else f"<contacts {i}>"
        missing = [c for c in _WORLD + _NORMAL if c not in cols]
        if missing:
            raise TableError(f"{name}: no {missing[0]} column: contact tables from "
                             "`camwhisker contact --pose` have them")  # fmt: skip
        p = _stack(cols, _WORLD)
        n = _stack(cols, _NORMAL)
        a = _stack(cols, _SHAFT) if all(c in cols for c in _SHAFT) else np.full(p.shape, np.nan)
        # The same point on consecutive rows is one pause's estimate.
        keep = np.isfinite(p).all(axis=1) & ~np.r_[False, np.all(p[1:] == p[:-1], axis=1)]
        d = np.tile(_travel(cols), (int(keep.sum()), 1))
        parts.append((p[keep], n[keep], a[keep], np.full(int(keep.sum()), i), d))
    p, n, a, t, d = (np.concatenate([q[k] for q in parts]) if parts else np.empty(0)
                     for k in range(5))  # fmt: skip
    return Surfels3(p.reshape(-1, 3), n.reshape(-1, 3), a.reshape(-1, 3), t.astype(int),
                    d.reshape(-1, 3))


def _travel(cols: dict) -> np.ndarray:
    """The unit direction from a table's first base position to its last (NaN without)."""
    if not all(c in cols for c in _BASE):
        return np.full(3, np.nan)
    b = _stack(cols, _BASE)
    b = b[np.isfinite(b).all(axis=1)]
    step = b[-1] - b[0] if len(b) > 1 else np.zeros(3)
    size = float(np.linalg.norm(step))
    return step / size if size > 0 else np.full(3, np.nan)


def read_surfels3(paths: list[str | Path]) -> Surfels3:
    """Surfels of contact table files (docs/sensor.md sections 7 and 9)."""
    tables = [read_columns(p, REQUIRED_COLUMNS, OPTIONAL_COLUMNS) for p in paths]
    return surfels_from_tables(tables, [str(p) for p in paths])


def _unit(a: float, b: float) -> np.ndarray:
    return np.array([math.sin(a) * math.cos(b), math.sin(a) * math.sin(b), math.cos(a)])


def _angles(v: np.ndarray) -> tuple[float, float]:
    v = v / np.linalg.norm(v)
    return math.acos(float(np.clip(v[2], -1.0, 1.0))), math.atan2(float(v[1]), float(v[0]))


def _geometry(model: str, x: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance (mm, positive outside) and unit outward normal at each point."""
    if model == "plane":
        n = _unit(x[0], x[1])
        return p @ n - x[2], np.tile(n, (p.shape[0], 1))
    if model == "sphere":
        v = p - x[:3]
        r = np.linalg.norm(v, axis=1)
        return r - abs(x[3]), v / np.maximum(r, 1e-9)[:, None]
    u = _unit(x[3], x[4])
    v = p - x[:3]
    radial = v - np.outer(v @ u, u)
    r = np.linalg.norm(radial, axis=1)
    return r - abs(x[5]), radial / np.maximum(r, 1e-9)[:, None]


def _normal_angle(model_n: np.ndarray, measured: np.ndarray, shaft: np.ndarray) -> np.ndarray:
    """Angle (rad) between a model normal and the measured one, across the shaft where
    known; 0 where no normal was measured or the model's lies along the shaft."""
    m = model_n
    has_shaft = np.isfinite(shaft).all(axis=1)
    a = np.where(has_shaft[:, None], shaft, 0.0)
    across = m - np.sum(m * a, axis=1)[:, None] * a
    size = np.linalg.norm(across, axis=1)
    ok = np.isfinite(measured).all(axis=1) & (size >= _ACROSS_MIN)
    across = across / np.maximum(size, 1e-9)[:, None]
    meas = np.where(ok[:, None], measured, 0.0)
    cos = np.sum(across * meas, axis=1)
    sin = np.linalg.norm(np.cross(across, meas), axis=1)
    return np.where(ok, np.arctan2(sin, cos), 0.0)


def _normal_sigma(s: Surfels3) -> np.ndarray:
    """Each measured normal's scale (rad): :data:`NORMAL_SIGMA_RAD` with the sideways drag
    of a base that moved across the plane of the shaft and the normal; the planar
    percepts' DIR_SIGMA_RAD where the table gives no travel or shaft."""
    if s.travel is None:
        return np.full(s.n, DIR_SIGMA_RAD)
    across = np.abs(np.sum(s.travel * np.cross(s.shaft, s.normal), axis=1))
    sigma = np.hypot(NORMAL_SIGMA_RAD, LATERAL_MU * across)
    return np.where(np.isfinite(sigma), sigma, DIR_SIGMA_RAD)


def _residuals(x: np.ndarray, model: str, s: Surfels3, centroid: np.ndarray) -> np.ndarray:
    dist, normal = _geometry(model, x, s.p_mm)
    parts = [dist / POINT_SIGMA_MM, _normal_angle(normal, s.normal, s.shaft) / _normal_sigma(s)]
    if model == "cylinder":
        parts.append([(x[:3] - centroid) @ _unit(x[3], x[4]) / _GAUGE_MM])
    return np.concatenate([np.atleast_1d(np.asarray(q, float)) for q in parts])


def _mean_normal(s: Surfels3) -> np.ndarray | None:
    n = s.normal[np.isfinite(s.normal).all(axis=1)]
    if not n.size or np.linalg.norm(n.sum(axis=0)) < 1e-9:
        return None
    m = n.sum(axis=0)
    return m / np.linalg.norm(m)


def _starts(model: str, s: Surfels3) -> list[np.ndarray]:
    p = s.p_mm
    centroid = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - centroid)
    mean_n = _mean_normal(s)
    if model == "plane":
        out = []
        for n in [v for v in (mean_n, vt[2]) if v is not None]:
            if mean_n is not None and n @ mean_n < 0:
                n = -n
            out.append(np.array([*_angles(n), float(np.median(p @ n))]))
        return out
    n = s.normal if mean_n is not None else np.zeros_like(p)
    n = np.where(np.isfinite(n), n, 0.0)
    if model == "sphere":
        return [np.array([*(p - r * n).mean(axis=0), r]) for r in _START_RADII_MM]
    axes = [vt[0]]
    good = n[np.linalg.norm(n, axis=1) > 0.5]
    if len(good) >= 2:
        axes.append(np.linalg.eigh(good.T @ good)[1][:, 0])  # normals lie across the axis
    out = []
    for u in axes:
        for r in _START_RADII_MM:
            c = (p - r * n).mean(axis=0)
            c = c + ((centroid - c) @ u) * u
            out.append(np.array([*c, *_angles(u), r]))
    return out


_K = {"plane": 3, "sphere": 4, "cylinder": 5}


def _public(model: str, x: np.ndarray, centroid: np.ndarray) -> dict:
    """Reported parameters (docs/sensor.md section 9) of a fitted vector."""
    if model == "plane":
        n = _unit(x[0], x[1])
        return {"normal_x": n[0], "normal_y": n[1], "normal_z": n[2], "distance_mm": x[2]}
    if model == "sphere":
        return {"center_x_mm": x[0], "center_y_mm": x[1], "center_z_mm": x[2],
                "radius_mm": abs(x[3])}
    u = _unit(x[3], x[4])
    u = u if u[np.argmax(np.abs(u))] > 0 else -u  # an axis has no sign: its largest part > 0
    c = x[:3] + ((centroid - x[:3]) @ u) * u
    return {"center_x_mm": c[0], "center_y_mm": c[1], "center_z_mm": c[2], "axis_x": u[0],
            "axis_y": u[1], "axis_z": u[2], "radius_mm": abs(x[5])}


def _intervals(model: str, res, centroid: np.ndarray, n: int, m: int) -> dict:
    """95 % intervals of the reported parameters by the delta method (NaN where singular)."""
    k = _K[model]
    sigma2 = float(np.sum(np.log1p(res.fun[:m] ** 2))) / max(m - k, 1) * ar1_inflation(res.fun[:n])
    try:
        cov = np.linalg.inv(res.jac.T @ res.jac) * sigma2
    except np.linalg.LinAlgError:
        cov = np.full((res.x.size,) * 2, np.nan)
    base = _public(model, res.x, centroid)
    jac = np.zeros((len(base), res.x.size))
    for i in range(res.x.size):
        h = np.zeros(res.x.size)
        h[i] = _STEP * max(1.0, abs(res.x[i]))
        up = _public(model, res.x + h, centroid)
        down = _public(model, res.x - h, centroid)
        jac[:, i] = [(up[k2] - down[k2]) / (2 * h[i]) for k2 in base]
    var = np.einsum("ij,jk,ik->i", jac, cov, jac)
    half = Z95 * np.sqrt(np.clip(var, 0.0, None))
    return {name: [base[name] - w, base[name] + w] for name, w in zip(base, half, strict=True)}


def _subset(s: Surfels3, keep: np.ndarray) -> Surfels3:
    travel = None if s.travel is None else s.travel[keep]
    return Surfels3(s.p_mm[keep], s.normal[keep], s.shaft[keep], s.table[keep], travel)


def _jackknife(model: str, s: Surfels3, x: np.ndarray, params: dict, intervals: dict) -> dict:
    """The intervals widened by the leave-one-table-out spread of the reported parameters
    (added in quadrature, Student's t with tables - 1 degrees of freedom)."""
    tables = np.unique(s.table)
    if tables.size < 2:
        return intervals
    estimates = []
    for g in tables:
        sub = _subset(s, s.table != g)
        res = least_squares(_residuals, x, loss="cauchy", f_scale=1.0,
                            args=(model, sub, sub.p_mm.mean(axis=0)))  # fmt: skip
        # Reported as the whole fit reports them (a cylinder's centre: nearest its centroid).
        estimates.append(_public(model, res.x, s.p_mm.mean(axis=0)))
    q = float(student_t.ppf(0.975, tables.size - 1))
    out = {}
    for name, value in params.items():
        v = np.array([e[name] for e in estimates])
        spread = math.sqrt((tables.size - 1) / tables.size * np.sum((v - v.mean()) ** 2))
        lo, hi = intervals[name]
        w = math.hypot((hi - lo) / 2.0, q * spread)
        out[name] = [value - w, value + w]
    return out


def fit_solid(model: str, s: Surfels3) -> Fit | None:
    """Robust least-squares fit of one model; None without a starting point."""
    if model not in _K:
        raise ValueError(f"unknown model {model!r} (known: {', '.join(MODELS)})")
    centroid = s.p_mm.mean(axis=0)
    best = None
    for x0 in _starts(model, s):
        res = least_squares(_residuals, x0, loss="cauchy", f_scale=1.0,
                            args=(model, s, centroid))  # fmt: skip
        if best is None or res.cost < best.cost:
            best = res
    if best is None:
        return None
    m = _n_contact_residuals(s)
    cost = float(np.sum(np.log1p(best.fun**2)))
    k = _K[model]
    params = _public(model, best.x, centroid)
    intervals = _jackknife(model, s, best.x, params, _intervals(model, best, centroid, s.n, m))
    return Fit(model, params, _floored(params, intervals), cost, cost + k * math.log(m), m,
               best.x)


def _floored(params: dict, intervals: dict) -> dict:
    """Each length's interval widened by :data:`SYSTEMATIC_MM` (in quadrature)."""
    out = {}
    for name, (lo, hi) in intervals.items():
        if name.endswith("_mm"):
            w = math.hypot((hi - lo) / 2.0, Z95 * SYSTEMATIC_MM)
            lo, hi = params[name] - w, params[name] + w
        out[name] = [lo, hi]
    return out


def _n_contact_residuals(s: Surfels3) -> int:
    """Contacts and their normals: the data the information criterion counts."""
    return 2 * s.n


def perceive_solid(s: Surfels3, models=MODELS) -> Percept:
    """Fit every model and choose by BIC; "none" with fewer than :data:`MIN_SURFELS` contacts."""
    m = _n_contact_residuals(s)
    none_cost = m * math.log1p(NONE_RESIDUAL**2)
    fits = {"none": Fit("none", {}, {}, none_cost, none_cost, m)}
    if s.n >= MIN_SURFELS:
        for model in models:
            f = fit_solid(model, s)
            if f is not None:
                fits[model] = f
    ranked = sorted(fits.values(), key=lambda f: f.bic)
    best, runner = ranked[0], (ranked[1] if len(ranked) > 1 else None)
    ratio = math.exp(min((runner.bic - best.bic) / 2.0, 700.0)) if runner else math.inf
    return Percept(best, fits, runner.model if runner else "", ratio, s.n)


def next_plane_run(fit: Fit, s: Surfels3, rise_deg: float = RISE_DEG) -> dict | None:
    """Active sensing for a plane: the turn of the first table's sweep (its travel and
    shaft together, about their plane's normal ``about``) after which the plane's trace in
    that sweep's plane rises at ``rise_deg`` from the travel, as the planar percepts turn a
    wall's next run (:func:`camwhisker.percept.percepts.steep_turn_deg`); None where the
    table gives no travel or shaft, or the plane lies in the sweep's plane."""
    if fit.model != "plane" or s.travel is None or not s.n:
        return None
    first = s.table == s.table[0]
    d, a = np.nanmean(s.travel[first], axis=0), np.nanmean(s.shaft[first], axis=0)
    about = np.cross(d, a)
    n = np.array([fit.params["normal_x"], fit.params["normal_y"], fit.params["normal_z"]])
    trace = np.cross(n, about)
    if not np.isfinite(about).all() or np.linalg.norm(about) < 1e-6 or \
            np.linalg.norm(trace) < 1e-6:
        return None
    about /= np.linalg.norm(about)
    e1 = d - (d @ about) * about
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(about, e1)
    rise = math.degrees(math.atan2(float(trace @ e2), float(trace @ e1))) % 180.0
    turn = (rise - rise_deg + 90.0) % 180.0 - 90.0
    return {"turn_deg": turn, "about_x": about[0], "about_y": about[1], "about_z": about[2]}


def _touch_candidates(fit: Fit, s: Surfels3) -> tuple[np.ndarray, np.ndarray]:
    """Points of a fitted sphere's or cylinder's surface (M, 3) and their outward normals."""
    r = fit.params["radius_mm"]
    c = np.array([fit.params[f"center_{k}_mm"] for k in "xyz"])
    if fit.model == "sphere":
        i = np.arange(_SPHERE_CANDIDATES) + 0.5
        polar = np.arccos(1.0 - 2.0 * i / _SPHERE_CANDIDATES)
        azimuth = math.pi * (1.0 + math.sqrt(5.0)) * i
        n = np.column_stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth),
                             np.cos(polar)])  # fmt: skip
        return c + r * n, n
    u = np.array([fit.params[f"axis_{k}"] for k in "xyz"])
    e1 = np.linalg.svd(u[None, :])[2][1]
    e2 = np.cross(u, e1)
    along = (s.p_mm - c) @ u
    reach = _AXIAL_REACH_RADII * r
    t = np.linspace(along.min() - reach, along.max() + reach, _AXIAL_CANDIDATES)
    a = np.linspace(0.0, 2.0 * math.pi, _ROUND_CANDIDATES, endpoint=False)
    n = np.repeat(np.cos(a)[:, None] * e1 + np.sin(a)[:, None] * e2, t.size, axis=0)
    return c + np.tile(t, a.size)[:, None] * u + r * n, n


def next_touch(fit: Fit, s: Surfels3) -> dict | None:
    """Active sensing for a sphere or cylinder: the point of the fitted surface where one
    more contact shrinks the parameters' confidence region most, and the outward normal
    there (touch it moving along -normal).

    D-optimal design: with J the fit's residual Jacobian and j the gradient of a contact's
    distance residual at a candidate point, a contact there shrinks the region's volume by
    1 / sqrt(1 + j^T (J^T J)^-1 j) (``shrink``); the candidate with the largest such term wins.
    The fit's Gauss-Newton information, without the Cauchy loss's weights. None for other
    models or a singular fit.
    """
    if fit.model not in ("sphere", "cylinder") or fit.x is None or not s.n:
        return None
    centroid = s.p_mm.mean(axis=0)
    q, n = _touch_candidates(fit, s)
    jac = np.empty((_residuals(fit.x, fit.model, s, centroid).size, fit.x.size))
    grad = np.empty((q.shape[0], fit.x.size))
    for i in range(fit.x.size):
        h = np.zeros(fit.x.size)
        h[i] = _STEP * max(1.0, abs(fit.x[i]))
        jac[:, i] = (_residuals(fit.x + h, fit.model, s, centroid)
                     - _residuals(fit.x - h, fit.model, s, centroid)) / (2 * h[i])  # fmt: skip
        grad[:, i] = (_geometry(fit.model, fit.x + h, q)[0]
                      - _geometry(fit.model, fit.x - h, q)[0]) / (2 * h[i] * POINT_SIGMA_MM)
    try:
        cov = np.linalg.inv(jac.T @ jac)
    except np.linalg.LinAlgError:
        return None
    gain = np.einsum("ij,jk,ik->i", grad, cov, grad)
    if not np.isfinite(gain).any():
        return None
    best = int(np.nanargmax(gain))
    names = ("point_x_mm", "point_y_mm", "point_z_mm", "normal_x", "normal_y", "normal_z")
    return {**dict(zip(names, map(float, [*q[best], *n[best]]), strict=True)),
            "shrink": 1.0 / math.sqrt(1.0 + float(gain[best]))}


def solid_record(p: Percept, s: Surfels3 | None = None) -> dict:
    """The percept as plain data (docs/sensor.md section 9): model, params, intervals_95,
    runner-up, evidence ratio, for a plane the turn of a steeper next run
    (:func:`next_plane_run`, from the surfels ``s``), for a sphere or cylinder the next
    touch (:func:`next_touch`), and every candidate's BIC."""
    return {"model": p.best.model, "params": p.best.params, "intervals_95": p.best.intervals,
            "runner_up": p.runner_up, "evidence_ratio": p.evidence_ratio,
            "n_surfels": p.n_surfels,
            "next_run": next_plane_run(p.best, s) if s is not None else None,
            "next_touch": next_touch(p.best, s) if s is not None else None,
            "candidates": {m: {"bic": f.bic, "cost": f.cost, "params": f.params}
                           for m, f in p.fits.items()}}  # fmt: skip
