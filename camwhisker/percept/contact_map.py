"""A 3-D contact map: contact points placed in W, a voxel grid of contact belief, a picture.

Seed paper 000 ("Egocentric processing") keeps contact in a 3-D array of voxels, cubes
of side 10 mm: each whisker's contact belief b (eq. 1) is put into the map at the
contact's location through a Gaussian spatial filter of width 25 mm, and an element-wise
maximum over the last second's samples gives the map with one second of memory. Here
the locations are the contact tables' world columns (docs/sensor.md section 9: px_mm,
py_mm, pz_mm from ``camwhisker contact --pose``), and

    belief[i, j, k] = max over points p of  b_p exp(-|c_ijk - p|^2 / (2 sigma^2))

with c_ijk = origin_mm + (i + 1/2, j + 1/2, k + 1/2) voxel_mm the voxel's centre. The
paper does not say what its filter's "width" measures; it is read as the Gaussian's
standard deviation (:data:`SIGMA_MM`), the usual meaning of a Gaussian filter's width
parameter (its full width at half maximum would make sigma 10.6 mm, about one voxel, and
the filter would hardly spread the map at all). With ``memory_s`` only the points within
that time of the last one enter (the paper's one second: the map at the last time);
without it, every point.

b is eq. 1 on the table's phi_deg: clip(phi / eta - 1, 0, 1). The contact table carries
no rest frames to measure eta from (:func:`~camwhisker.contact.belief.eta_from_rest`), so
its default applies eq. 1's own rule, the no-contact peak plus 50 %
(:data:`~camwhisker.contact.belief.ETA_FACTOR`), to the package's bound on that peak, the
contact threshold :data:`~camwhisker.contact.stage.CONTACT_PHI_DEG` (about 20 times the
noise of a pause's phi): eta 1.5 deg, b = 1 from phi = 3 deg.

Files: :func:`write_ply` (the points, for CloudCompare, MeshLab, Open3D),
:func:`write_grid_npz` (the grid), :func:`plot_contact_map` (the points coloured by eq.
11's Z in 3-D and in three projections, with a fitted object from a percept file).
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camwhisker import __version__
from camwhisker.contact.belief import ETA_FACTOR, contact_belief
from camwhisker.contact.stage import CONTACT_PHI_DEG
from camwhisker.files.atomic import atomic_write_bytes
from camwhisker.files.jsonfile import dumps
from camwhisker.files.tables import TableError, read_columns

__all__ = ["VOXEL_MM", "SIGMA_MM", "PAD_SIGMAS", "DEFAULT_ETA_DEG", "MAX_VOXELS", "PLY_PROPERTIES",
           "ContactMapError", "ContactPoints", "BeliefGrid", "PerceptShape", "r_sd_mm",
           "read_contact_points", "write_ply", "belief_grid", "write_grid_npz", "read_percept",
           "object_lines", "plot_contact_map"]  # fmt: skip

#: Voxel side (mm): seed paper 000's cubes of side 10 mm.
VOXEL_MM = 10.0
#: The Gaussian filter's standard deviation (mm): the paper's "width 25 mm" (module docstring).
SIGMA_MM = 25.0
#: The grid reaches this many sigma past the points: there a point's share has fallen to
#: exp(-4.5) = 1.1 % of its belief, under any use of the map.
PAD_SIGMAS = 3.0
#: eta of eq. 1 when none is given (deg): the paper's peak-plus-50 % on the contact threshold.
DEFAULT_ETA_DEG = ETA_FACTOR * CONTACT_PHI_DEG
#: Most voxels a grid may have: 80 MB of float32, a 2.7 m cube at 10 mm; more is a unit slip.
MAX_VOXELS = 20_000_000
#: Elements (points x voxels) evaluated at once: 32 MB of float64 bounds the work array.
CHUNK_ELEMENTS = 1 << 22
#: The world columns a table must have, and the others read where it has them.
POINT_COLUMNS = ("px_mm", "py_mm", "pz_mm", "nx", "ny", "nz")
NEEDED_COLUMNS = ("t_s", "phi_deg", *POINT_COLUMNS)
OPTIONAL_COLUMNS = ("z_score", "sigma_gm_mm", "sigma_mf_mm")
#: The PLY's vertex properties and their types (PLY names): the position and normal as
#: float32, which holds mm to 3e-5 mm at 300 mm; time as double (float32 steps 8 ms at 1 day).
PLY_PROPERTIES = (("x", "float"), ("y", "float"), ("z", "float"), ("nx", "float"),
                  ("ny", "float"), ("nz", "float"), ("belief", "float"), ("z_score", "float"),
                  ("r_sd_mm", "float"), ("t_s", "double"), ("table", "int"))  # fmt: skip
_NUMPY_OF_PLY = {"float": "<f4", "double": "<f8", "int": "<i4"}
#: The paper's reading of eq. 11's |Z|: < 0.5 expected, 0.5-1, > 1 a probable GM error.
Z_BANDS = (0.5, 1.0)
Z_COLOURS = ("#2c7bb6", "#fdae61", "#d7191c")
#: Each model of a percept file (docs/sensor.md section 9) and the params it needs.
MODEL_PARAMS = {
    "sphere": ("center_x_mm", "center_y_mm", "center_z_mm", "radius_mm"),
    "cylinder": ("center_x_mm", "center_y_mm", "center_z_mm", "axis_x", "axis_y", "axis_z",
                 "radius_mm"),
    "plane": ("normal_x", "normal_y", "normal_z", "distance_mm"),
}
#: Points along a drawn circle: a 2-degree step, smooth at the figure's size.
CIRCLE_POINTS = 181
#: Lines each way in a plane's or a sphere's wireframe.
WIRE_LINES = 7


class ContactMapError(ValueError):
    """Input a map cannot be made from; the message names the file or the option."""


@dataclass(frozen=True)
class ContactPoints:
    """Contact points in W from one or more contact tables (rows with a finite point).

    Attributes
    ----------
    p_mm : ndarray, shape (N, 3)
        The contact point in W (mm).
    normal : ndarray, shape (N, 3)
        The surface normal's estimate, unit, in W.
    belief : ndarray, shape (N,)
        Eq. 1's b from the row's phi_deg, in [0, 1] (NaN where phi is).
    z_score : ndarray, shape (N,)
        Eq. 11's Z (NaN where the table has none).
    r_sd_mm : ndarray, shape (N,)
        The spread of r_hat (mm): sigma_GM and sigma_MF combined by inverse variance.
    t_s : ndarray, shape (N,)
        The row's time (s, the table's camera clock).
    table : ndarray of int, shape (N,)
        Which input table each point came from (0-based).
    row : ndarray of int, shape (N,)
        Its data row in that table (0-based, the header not counted).
    sources : tuple of str
        The tables, in input order.
    eta_deg : float
        eta of eq. 1.
    """

    p_mm: np.ndarray
    normal: np.ndarray
    belief: np.ndarray
    z_score: np.ndarray
    r_sd_mm: np.ndarray
    t_s: np.ndarray
    table: np.ndarray
    row: np.ndarray
    sources: tuple[str, ...]
    eta_deg: float

    @property
    def n(self) -> int:
        return int(self.p_mm.shape[0])


def r_sd_mm(sigma_gm_mm, sigma_mf_mm) -> np.ndarray:
    """The spread of r_hat (mm): 1 / sqrt(1/sigma_GM^2 + 1/sigma_MF^2) where both are finite
    and positive, the one that is elsewhere, NaN where neither is.

    Parameters
    ----------
    sigma_gm_mm, sigma_mf_mm : array_like, shape (N,)
    """
    g = np.asarray(sigma_gm_mm, float)
    m = np.asarray(sigma_mf_mm, float)
    with np.errstate(invalid="ignore"):
        g = np.where(np.isfinite(g) & (g > 0), g, np.nan)
        m = np.where(np.isfinite(m) & (m > 0), m, np.nan)
    # Inverse variances add; a missing estimate adds nothing (its NaN taken as 0).
    w = np.nan_to_num(1.0 / g**2) + np.nan_to_num(1.0 / m**2)
    with np.errstate(divide="ignore"):
        return np.where(w > 0, 1.0 / np.sqrt(w), np.nan)


def _header(path: Path) -> list[str]:
    try:
        with open(path, encoding="utf-8", newline="") as fh:
            return [h.strip() for h in next(csv.reader(fh), [])]
    except OSError as exc:
        raise ContactMapError(f"{path}: cannot read ({exc.strerror})") from exc


def _table_points(path: Path, eta_deg: float) -> dict:
    """One table's rows with a finite point, as the columns of :class:`ContactPoints`."""
    header = _header(path)
    for need in NEEDED_COLUMNS:
        if need not in header:
            why = ("contact tables from `camwhisker contact --pose` have them"
                   if need in POINT_COLUMNS else "it is not a contact table")
            raise ContactMapError(f"{path} has no {need} column: {why}")
    try:
        cols = read_columns(path, NEEDED_COLUMNS, OPTIONAL_COLUMNS)
    except TableError as exc:
        raise ContactMapError(str(exc)) from exc
    p = np.column_stack([cols[c] for c in POINT_COLUMNS[:3]])
    keep = np.isfinite(p).all(axis=1)
    nan = np.full(keep.size, np.nan)
    return {
        "p_mm": p[keep],
        "normal": np.column_stack([cols[c] for c in POINT_COLUMNS[3:]])[keep],
        "belief": contact_belief(cols["phi_deg"], eta_deg)[keep],  # Eq. (1)
        "z_score": cols.get("z_score", nan)[keep],
        "r_sd_mm": r_sd_mm(cols.get("sigma_gm_mm", nan), cols.get("sigma_mf_mm", nan))[keep],
        "t_s": cols["t_s"][keep],
        "row": np.flatnonzero(keep),
    }


def read_contact_points(paths, eta_deg: float = DEFAULT_ETA_DEG) -> ContactPoints:
    """The contact points of contact tables with the world columns (section 9).

    Parameters
    ----------
    paths : sequence of path
        Contact tables (``camwhisker contact --pose``); their rows with px_mm, py_mm and
        pz_mm all finite are the points.
    eta_deg : float
        eta of eq. 1 (deg), > 0.

    Raises
    ------
    ContactMapError
        A table without a needed column (named), an unreadable cell, a bad eta, or no point
        in any table.
    """
    if not (math.isfinite(eta_deg) and eta_deg > 0):
        raise ContactMapError(f"eta_deg {eta_deg}: must be a positive, finite angle (deg)")
    paths = [Path(p) for p in paths]
    if not paths:
        raise ContactMapError("no contact table given")
    parts = [_table_points(p, eta_deg) for p in paths]
    total = sum(part["t_s"].size for part in parts)
    if total == 0:
        raise ContactMapError(f"{', '.join(map(str, paths))}: no contact point: no row has "
                              "px_mm, py_mm and pz_mm (they are empty where r_hat_mm is, "
                              "before the whisker touches)")  # fmt: skip
    cat = {k: np.concatenate([part[k] for part in parts]) for k in parts[0]}
    table = np.concatenate([np.full(part["t_s"].size, i) for i, part in enumerate(parts)])
    return ContactPoints(table=table.astype(int), sources=tuple(map(str, paths)),
                         eta_deg=float(eta_deg), **cat)  # fmt: skip


def _ply_vertices(points: ContactPoints) -> np.ndarray:
    values = {"x": points.p_mm[:, 0], "y": points.p_mm[:, 1], "z": points.p_mm[:, 2],
              "nx": points.normal[:, 0], "ny": points.normal[:, 1], "nz": points.normal[:, 2],
              "belief": points.belief, "z_score": points.z_score, "r_sd_mm": points.r_sd_mm,
              "t_s": points.t_s, "table": points.table}  # fmt: skip
    out = np.empty(points.n, [(name, _NUMPY_OF_PLY[kind]) for name, kind in PLY_PROPERTIES])
    for name, _ in PLY_PROPERTIES:
        out[name] = values[name]
    return out


def write_ply(path, points: ContactPoints, comments=()) -> None:
    """Write the points as a binary little-endian PLY (one vertex each), atomically.

    Vertex properties: :data:`PLY_PROPERTIES` (x, y, z in mm in W; NaN where a value is
    undefined, e.g. z_score without MF). ``comments``: lines for the header (a newline in
    one is turned into a space: the header is line-based).
    """
    lines = ["ply", "format binary_little_endian 1.0",
             f"comment camwhisker {__version__} contact map: points in W (mm), docs/map.md",
             f"comment belief: eq. 1 with eta {points.eta_deg:g} deg"]  # fmt: skip
    lines += [f"comment {' '.join(str(c).split())}" for c in comments]
    lines += [f"element vertex {points.n}"]
    lines += [f"property {kind} {name}" for name, kind in PLY_PROPERTIES]
    lines += ["end_header"]
    header = ("\n".join(lines) + "\n").encode("ascii", errors="replace")
    atomic_write_bytes(path, header + _ply_vertices(points).tobytes())


@dataclass(frozen=True)
class BeliefGrid:
    """A voxel grid of contact belief (module docstring).

    Attributes
    ----------
    belief : ndarray of float32, shape (nx, ny, nz)
        Each voxel's belief in [0, 1].
    origin_mm : ndarray, shape (3,)
        The grid's lowest corner in W (mm): voxel (i, j, k) spans origin_mm + [i, i + 1)
        voxel_mm along x, and so on.
    voxel_mm, sigma_mm : float
    memory_s : float or None
        Only points within this of ``t_last_s`` entered; None: all.
    t_last_s : float
        The last point's time (s).
    n_points : int
        The points that entered.
    """

    belief: np.ndarray
    origin_mm: np.ndarray
    voxel_mm: float
    sigma_mm: float
    memory_s: float | None
    t_last_s: float
    n_points: int

    @property
    def upper_mm(self) -> np.ndarray:
        """The grid's highest corner in W (mm), shape (3,)."""
        return self.origin_mm + np.array(self.belief.shape) * self.voxel_mm

    def centres_mm(self, axis: int) -> np.ndarray:
        """The voxels' centres along ``axis`` (0, 1, 2 for x, y, z), shape (n_axis,)."""
        return self.origin_mm[axis] + (np.arange(self.belief.shape[axis]) + 0.5) * self.voxel_mm


def _positive(name: str, value: float, unit: str) -> None:
    if not (math.isfinite(value) and value > 0):
        raise ContactMapError(f"{name} {value}: must be a positive, finite {unit}")


def _in_memory(points: ContactPoints, memory_s: float | None) -> np.ndarray:
    """Which points enter the map: all, or those within ``memory_s`` of the last time."""
    if memory_s is None:
        return np.ones(points.n, bool)
    if not (math.isfinite(memory_s) and memory_s >= 0):
        raise ContactMapError(f"memory_s {memory_s}: must be a finite time >= 0 (s)")
    t = points.t_s
    with np.errstate(invalid="ignore"):
        return t >= _last_time(t) - memory_s


def _last_time(t_s: np.ndarray) -> float:
    """The last finite time (s), NaN where none is."""
    finite = t_s[np.isfinite(t_s)]
    return float(finite.max()) if finite.size else math.nan


def _splat(p_mm: np.ndarray, b: np.ndarray, grid: BeliefGrid) -> None:
    """Max of b exp(-d^2 / 2 sigma^2) into ``grid.belief``, over chunks of points and of x
    slabs so no work array exceeds :data:`CHUNK_ELEMENTS`."""
    nx, ny, nz = grid.belief.shape
    centres = [grid.centres_mm(a) for a in range(3)]
    per_point = max(1, CHUNK_ELEMENTS // (nx * ny * nz))
    slab = max(1, min(nx, CHUNK_ELEMENTS // (ny * nz)))
    for lo in range(0, b.size, per_point):
        s = slice(lo, lo + per_point)
        # The Gaussian is separable: each point's kernel is the outer product of three 1-D ones.
        g = [np.exp(-((centres[a][None, :] - p_mm[s, a, None]) ** 2) / (2.0 * grid.sigma_mm**2))
             for a in range(3)]  # fmt: skip
        for i in range(0, nx, slab):
            gx = b[s, None] * g[0][:, i:i + slab]
            block = gx[:, :, None, None] * g[1][:, None, :, None] * g[2][:, None, None, :]
            np.maximum(grid.belief[i:i + slab], block.max(axis=0), out=grid.belief[i:i + slab])


def belief_grid(points: ContactPoints, voxel_mm: float = VOXEL_MM, sigma_mm: float = SIGMA_MM,
                memory_s: float | None = None) -> BeliefGrid:
    """The voxel grid of contact belief (module docstring) over the points' box padded by
    :data:`PAD_SIGMAS` sigma.

    Parameters
    ----------
    points : ContactPoints
    voxel_mm : float
        Voxel side (mm), > 0.
    sigma_mm : float
        The Gaussian's standard deviation (mm), > 0.
    memory_s : float or None
        Only the points within this of the last point's time (s, >= 0); None: all. A point's
        belief that is NaN (phi undefined) counts as 0.

    Raises
    ------
    ContactMapError
        A bad option (named), or a grid of more than :data:`MAX_VOXELS` voxels.
    """
    _positive("voxel_mm", voxel_mm, "length (mm)")
    _positive("sigma_mm", sigma_mm, "length (mm)")
    use = _in_memory(points, memory_s)
    if not use.any():
        raise ContactMapError(f"memory_s {memory_s:g}: no point has a finite time t_s")
    p = points.p_mm[use]
    pad = PAD_SIGMAS * sigma_mm
    lo, hi = p.min(axis=0) - pad, p.max(axis=0) + pad
    shape = np.maximum(1, np.ceil((hi - lo) / voxel_mm)).astype(int)
    if np.prod(shape.astype(float)) > MAX_VOXELS:
        raise ContactMapError(
            f"voxel_mm {voxel_mm:g}: the points' box padded by {PAD_SIGMAS:g} sigma, "
            f"{' x '.join(f'{v:.0f}' for v in hi - lo)} mm, makes "
            f"{' x '.join(map(str, shape))} voxels, more than {MAX_VOXELS:,}: take larger voxels")
    grid = BeliefGrid(belief=np.zeros(tuple(shape), np.float32), origin_mm=lo,
                      voxel_mm=float(voxel_mm), sigma_mm=float(sigma_mm), memory_s=memory_s,
                      t_last_s=_last_time(points.t_s), n_points=int(use.sum()))  # fmt: skip
    _splat(p, np.nan_to_num(points.belief[use], nan=0.0), grid)
    return grid


def write_grid_npz(path, grid: BeliefGrid, provenance: dict | None = None) -> None:
    """Save the grid as an npz, atomically: ``belief`` (float32, (nx, ny, nz)),
    ``origin_mm`` (3,), ``voxel_mm``, ``sigma_mm`` and ``provenance`` (a strict JSON string:
    the grid's definition, memory, last time and point count, plus ``provenance``)."""
    record = {
        "definition": "belief[i,j,k] = max over points of b * exp(-|c - p|^2 / (2 sigma_mm^2)), "
                      "c = origin_mm + (i + 0.5, j + 0.5, k + 0.5) * voxel_mm (W, mm)",
        "memory_s": grid.memory_s,
        "t_last_s": grid.t_last_s,
        "n_points": grid.n_points,
        **(provenance or {}),
    }
    buf = io.BytesIO()
    np.savez(buf, belief=grid.belief, origin_mm=grid.origin_mm, voxel_mm=grid.voxel_mm,
             sigma_mm=grid.sigma_mm, provenance=np.array(dumps(record)))  # fmt: skip
    atomic_write_bytes(path, buf.getvalue())


# ------------------------------------------------------------------ the picture


@dataclass(frozen=True)
class PerceptShape:
    """An object from a percept file (docs/sensor.md section 9): its model and params."""

    model: str
    params: dict
    source: str


def read_percept(path) -> PerceptShape:
    """The model and params of a percept JSON (``camwhisker percept`` on world tables).

    Models other than sphere, cylinder and plane are returned as they are (nothing is
    drawn for them); a known model must have each of its params, finite, its radius
    positive and its axis or normal not zero.

    Raises
    ------
    ContactMapError
        Not JSON, no model, or a missing or bad param (named).
    """
    try:
        record = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise ContactMapError(f"{path}: cannot read ({exc.strerror})") from exc
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ContactMapError(f"{path}: not a percept file: not JSON ({exc})") from exc
    if not isinstance(record, dict) or not isinstance(record.get("model"), str):
        raise ContactMapError(f"{path}: not a percept file: no model (docs/sensor.md section 9)")
    model = record["model"]
    params = record.get("params") or {}
    for name in MODEL_PARAMS.get(model, ()):
        v = params.get(name) if isinstance(params, dict) else None
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise ContactMapError(f"{path}: {model} param {name}: {v!r}, expected a number")
    if model in ("sphere", "cylinder") and not params["radius_mm"] > 0:
        raise ContactMapError(f"{path}: {model} radius_mm {params['radius_mm']}: must be > 0")
    key = {"cylinder": "axis", "plane": "normal"}.get(model)
    if key and not any(params[f"{key}_{c}"] for c in "xyz"):
        raise ContactMapError(f"{path}: {model} {key} is zero: expected a unit vector")
    return PerceptShape(model, dict(params) if isinstance(params, dict) else {}, str(path))


def _circle(centre, u, v, radius: float) -> np.ndarray:
    """A circle in 3-D, shape (CIRCLE_POINTS, 3): centre + radius (cos a u + sin a v)."""
    a = np.linspace(0.0, 2.0 * np.pi, CIRCLE_POINTS)[:, None]
    return np.asarray(centre) + radius * (np.cos(a) * u + np.sin(a) * v)


def _basis(w) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """w made unit and two unit vectors across it, a right-handed (u, v, w)."""
    w = np.asarray(w, float) / np.linalg.norm(w)
    helper = np.eye(3)[int(np.argmin(np.abs(w)))]
    u = np.cross(w, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(w, u), w


def _sphere_lines(c, r: float, view: int | None) -> list[np.ndarray]:
    e = np.eye(3)
    if view is not None:  # a sphere's outline seen along an axis: the great circle across it
        keep = [a for a in range(3) if a != view]
        return [_circle(c, e[keep[0]], e[keep[1]], r)]
    lines = []
    for z in np.linspace(-r, r, WIRE_LINES + 2)[1:-1]:  # latitude circles
        lines.append(_circle(c + z * e[2], e[0], e[1], math.sqrt(r * r - z * z)))
    for a in np.linspace(0.0, np.pi, WIRE_LINES, endpoint=False):  # meridians
        lines.append(_circle(c, math.cos(a) * e[0] + math.sin(a) * e[1], e[2], r))
    return lines


def _cylinder_lines(c, axis, r: float, p_mm: np.ndarray, view: int | None) -> list[np.ndarray]:
    u, v, w = _basis(axis)
    t = (p_mm - c) @ w  # the axis's stretch over the points
    t0, t1 = float(t.min()), float(t.max())
    if t1 - t0 < r:  # points in one ring: draw a squat piece, one radius long
        t0, t1 = (t0 + t1 - r) / 2, (t0 + t1 + r) / 2
    ends = [c + t0 * w, c + t1 * w]
    lines = [np.array(ends)] + [_circle(e, u, v, r) for e in ends]
    if view is None:
        sides = [math.cos(a) * u + math.sin(a) * v
                 for a in np.linspace(0, 2 * np.pi, 2 * WIRE_LINES, endpoint=False)]
    else:  # the outline seen along axis `view`: the sides across both the axis and the view
        s = np.cross(w, np.eye(3)[view])
        sides = [s / np.linalg.norm(s), -s / np.linalg.norm(s)] if np.linalg.norm(s) > 0 else []
    return lines + [np.array([ends[0] + r * s, ends[1] + r * s]) for s in sides]


def _plane_lines(n, d: float, p_mm: np.ndarray) -> list[np.ndarray]:
    u, v, w = _basis(n)
    d = d / np.linalg.norm(n)  # the plane n.p = d with n made unit
    a, b = p_mm @ u, p_mm @ v  # the points' extent along the plane
    lines = []
    for s in np.linspace(a.min(), a.max(), WIRE_LINES):
        lines.append(np.array([s * u + t * v + d * w for t in (b.min(), b.max())]))
    for t in np.linspace(b.min(), b.max(), WIRE_LINES):
        lines.append(np.array([s * u + t * v + d * w for s in (a.min(), a.max())]))
    return lines


def object_lines(shape: PerceptShape, p_mm: np.ndarray, view: int | None = None
                 ) -> list[np.ndarray]:  # fmt: skip
    """Polylines (each shape (M, 3), W, mm) that draw a percept's object near the points.

    ``view`` None: a wireframe for a 3-D view; 0, 1 or 2: lines whose projection along
    that axis outlines the object (a sphere's circle, a cylinder's sides and ends). A
    cylinder is drawn over the points' stretch along its axis, a plane as a patch over
    their extent on it. Other models: no line.
    """
    q = shape.params
    p_mm = np.asarray(p_mm, float).reshape(-1, 3)
    if shape.model == "sphere":
        c = np.array([q["center_x_mm"], q["center_y_mm"], q["center_z_mm"]], float)
        return _sphere_lines(c, float(q["radius_mm"]), view)
    if shape.model == "cylinder":
        c = np.array([q["center_x_mm"], q["center_y_mm"], q["center_z_mm"]], float)
        axis = np.array([q["axis_x"], q["axis_y"], q["axis_z"]], float)
        return _cylinder_lines(c, axis, float(q["radius_mm"]), p_mm, view)
    if shape.model == "plane":
        n = np.array([q["normal_x"], q["normal_y"], q["normal_z"]], float)
        return _plane_lines(n, float(q["distance_mm"]), p_mm)
    return []


def _z_colours(z: np.ndarray) -> list:
    """Each point's colour: eq. 11's |Z| in the paper's bands, grey where Z is undefined."""
    a = np.abs(np.asarray(z, float))
    band = np.searchsorted(Z_BANDS, np.nan_to_num(a, nan=0.0), side="right")
    return [Z_COLOURS[k] if math.isfinite(x) else "0.6" for k, x in zip(band, a, strict=True)]


def _legend_handles():
    from matplotlib.lines import Line2D

    labels = (f"|Z| < {Z_BANDS[0]:g} (eq. 11: expected)",
              f"{Z_BANDS[0]:g} <= |Z| < {Z_BANDS[1]:g}",
              f"|Z| >= {Z_BANDS[1]:g} (GM probably wrong)")  # fmt: skip
    handles = [Line2D([], [], ls="", marker="o", color=c, label=t)
               for c, t in zip(Z_COLOURS, labels, strict=True)]
    handles.append(Line2D([], [], ls="", marker="o", color="0.6", label="Z undefined"))
    return handles


def plot_contact_map(points: ContactPoints, path, how: str = "",
                     shape: PerceptShape | None = None) -> None:
    """A PNG: the points in 3-D and projected on x-y, x-z and y-z (W, mm), coloured by eq.
    11's |Z|, with the percept's object (``shape``) drawn dashed where it is given."""
    from camwhisker.files.figures import new_figure, save_figure

    fig, axes = new_figure((11.0, 10.0), nrows=2, ncols=2)
    axes[0, 0].remove()
    ax3 = fig.add_subplot(2, 2, 1, projection="3d")
    p = points.p_mm
    colours = _z_colours(points.z_score)
    ax3.scatter(p[:, 0], p[:, 1], p[:, 2], s=4, c=colours, depthshade=False)
    label = f"percept: {shape.model}" if shape else None
    for line in object_lines(shape, p) if shape else []:
        ax3.plot(line[:, 0], line[:, 1], line[:, 2], color="C4", lw=0.7, ls="--")
    ax3.set(xlabel="x (mm)", ylabel="y (mm)", zlabel="z (mm)", aspect="equal",
            title=f"{points.n} contacts in W from {len(points.sources)} table(s)")
    for ax, (i, j) in zip((axes[0, 1], axes[1, 0], axes[1, 1]), ((0, 1), (0, 2), (1, 2)),
                          strict=True):  # fmt: skip
        ax.scatter(p[:, i], p[:, j], s=4, c=colours)
        view = 3 - i - j  # the axis the projection drops
        for line in object_lines(shape, p, view) if shape else []:
            ax.plot(line[:, i], line[:, j], color="C4", lw=1.2, ls="--")
        ax.set(xlabel=f"{'xyz'[i]} (mm)", ylabel=f"{'xyz'[j]} (mm)", aspect="equal",
               title=f"{'xyz'[i]}-{'xyz'[j]}")  # fmt: skip
    handles = _legend_handles()
    if shape:
        from matplotlib.lines import Line2D

        drawn = shape.model in MODEL_PARAMS
        handles.append(Line2D([], [], color="C4", ls="--",
                              label=label + ("" if drawn else " (nothing to draw)")))
    fig.legend(handles=handles, loc="outside lower center", ncols=3, fontsize=8)
    save_figure(fig, path, how or "contact map")
