"""Surfels from contact tables: a point, a direction along the surface and a belief.

A surfel (BIOTACT, eqs. 1-2) is what one contact says about the object: the
contact point (eq. 12's x_hat, y_hat), a direction parallel to the surface
there and the belief that the contact happened. Here

- the point is eq. 12's, one per stage pause (the table repeats a pause's
  estimate on each of its frames), from the table's r_hat (the fused
  estimate) where the fusion kept GM (p_gm_good at or above
  :data:`~camwhisker.contact.fusion.KEEP_GM_POSTERIOR` and r_hat equal to
  r_gm: in a slip the fusion takes a line through the bias off GM whatever
  p_gm_good says) and from r_mf where it did not (when the table has those
  columns and MF lies inside its table): there GM is broken by slip, and the
  fused correction, a mean of the GM-MF difference over several pauses, lags a
  bias that grows with every pause of the slide, while MF follows it. Such a
  point carries its error, which lies along the whisker (MF errs in r): the
  calibration's sigma_MF at its phi times the unit vector from the base to the
  point;
- the direction is that of the chord between the neighbouring contacts of the
  same table (central difference), left undefined (NaN) where they lie closer
  than :data:`MIN_CHORD_MM` (a stuck contact says nothing about the surface);
- the belief is 1 for a row with a contact estimate (r_hat defined: the stage
  has travelled past the contact onset) and 0 for the whisker's base, where no
  object can be. Z does not lower the belief: it says which estimate of r to
  trust, not whether there was a contact, and a sliding contact (the one
  that traces a surface) has Z far above 1 on every pause.

Each table may carry a pose: its stage frame (x along the travel, y along the
whisker's rest axis) placed in a common frame by an origin and a rotation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camwhisker.contact.fusion import KEEP_GM_POSTERIOR
from camwhisker.contact.shape import reconstruct
from camwhisker.files.tables import TableError, read_columns

__all__ = ["Pose", "Surfels", "surfels_from_columns", "read_surfels", "merge", "MIN_CHORD_MM",
           "REQUIRED_COLUMNS", "OPTIONAL_COLUMNS"]

# Neighbouring contacts closer than this give no direction: it is the
# contact points' own scatter (fused r_hat, ~0.2-0.3 mm) times a few.
MIN_CHORD_MM = 0.8
#: What a contact table must have (docs/sensor.md section 7).
REQUIRED_COLUMNS = ("t_s", "x_mm", "phi_deg", "x_hat_mm", "r_hat_mm")
#: Columns used where the table has them (camwhisker contact writes them).
OPTIONAL_COLUMNS = ("y_hat_mm", "r_mf_mm", "p_gm_good", "sigma_mf_mm", "phi_pause_deg",
                    "dz_pause_mm", "dz_mm", "mf_outside", "x_mf_mm", "y_mf_mm")


@dataclass(frozen=True)
class Pose:
    """A stage frame in the common frame: common = (x0, y0) + R(angle) stage."""

    x0_mm: float = 0.0
    y0_mm: float = 0.0
    angle_deg: float = 0.0

    def apply(self, xy: np.ndarray) -> np.ndarray:
        a = math.radians(self.angle_deg)
        rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        return xy @ rot.T + np.array([self.x0_mm, self.y0_mm])

    def rotate(self, v: np.ndarray) -> np.ndarray:
        return Pose(0.0, 0.0, self.angle_deg).apply(v)


@dataclass(frozen=True)
class Surfels:
    """Contacts as surfels and the base positions as free space (common frame).

    xy_mm : shape (N, 2); dir : shape (N, 2), unit or NaN; belief : shape (N,);
    table : shape (N,), which input each came from; free_xy_mm : shape (M, 2);
    spread : shape (N, 2), a point's error along the whisker (mm): sigma_MF times the unit
    vector from the base to a point from MF's r, zero for a fused one.
    """

    xy_mm: np.ndarray
    dir: np.ndarray
    belief: np.ndarray
    table: np.ndarray
    free_xy_mm: np.ndarray
    spread: np.ndarray

    @property
    def n(self) -> int:
        return int(self.xy_mm.shape[0])


def _travel_sign(x_mm) -> float:
    x = np.asarray(x_mm, float)
    x = x[np.isfinite(x)]
    return -1.0 if x.size > 1 and x[-1] < x[0] else 1.0


def _points(cols: dict):
    """Each row's contact point: eq. 12 with r_hat, or with r_mf where the fusion did not keep
    GM (p_gm_good below KEEP_GM_POSTERIOR, or r_hat not r_gm: a slip; a row without
    p_gm_good or sigma_mf_mm keeps r_hat). The table's own MF point (x_mf_mm, y_mf_mm: on
    the bent whisker) where it has one, else eq. 12's. Returns x, y and sigma_MF where MF's
    was taken (NaN elsewhere)."""
    x_hat = np.asarray(cols["x_hat_mm"], float)
    phi = np.asarray(cols.get("phi_pause_deg", cols["phi_deg"]), float)
    r_hat = np.asarray(cols["r_hat_mm"], float)
    # A table without dz (not the contract's) is taken as one whose plate did not move.
    dz = np.asarray(cols.get("dz_pause_mm", cols.get("dz_mm", np.zeros(phi.shape))), float)
    if "y_hat_mm" in cols:
        y_hat = np.asarray(cols["y_hat_mm"], float)
    else:
        y_hat = r_hat * np.cos(np.radians(phi)) - dz  # Eq. (12)
    if any(k not in cols for k in ("r_mf_mm", "p_gm_good", "sigma_mf_mm")):
        return x_hat, y_hat, np.full(x_hat.shape, np.nan)
    r_mf = np.asarray(cols["r_mf_mm"], float)
    sigma = np.asarray(cols["sigma_mf_mm"], float)
    with np.errstate(invalid="ignore"):
        r_gm = np.asarray(cols.get("r_gm_mm", r_hat), float)
        # A slip's r_hat is GM less the slide's bias line whatever p_gm_good says: not GM's.
        not_gm = ((np.asarray(cols["p_gm_good"], float) < KEEP_GM_POSTERIOR)
                  | (np.isfinite(r_gm) & (r_hat != r_gm)))
        use_mf = not_gm & np.isfinite(r_mf) & np.isfinite(sigma)
    if "mf_outside" in cols:  # MF clamped at its table's edge says nothing about r
        use_mf &= np.asarray(cols["mf_outside"], float) == 0
    use_mf &= np.isfinite(x_hat)
    if "x_mf_mm" in cols and "y_mf_mm" in cols:
        x_mf, y_mf = (np.asarray(cols[k], float) for k in ("x_mf_mm", "y_mf_mm"))
    else:
        x_mf, y_mf = reconstruct(cols["x_mm"], r_mf, phi, dz, _travel_sign(cols["x_mm"]))
    return (np.where(use_mf, x_mf, x_hat), np.where(use_mf, y_mf, y_hat),
            np.where(use_mf, sigma, np.nan))


def _pause_points(x_hat, y_hat):
    """Indices of the first row of each run of equal (x_hat, y_hat): one per pause."""
    good = np.flatnonzero(np.isfinite(x_hat) & np.isfinite(y_hat))
    if good.size == 0:
        return good
    xy = np.c_[x_hat[good], y_hat[good]]
    new = np.r_[True, np.any(xy[1:] != xy[:-1], axis=1)]
    return good[new]


def _directions(xy: np.ndarray) -> np.ndarray:
    """Unit chord between each point's neighbours (one-sided at the ends); NaN if too short."""
    n = xy.shape[0]
    out = np.full((n, 2), np.nan)
    for i in range(n):
        a, b = xy[max(i - 1, 0)], xy[min(i + 1, n - 1)]
        chord = b - a
        length = float(np.hypot(*chord))
        if length >= MIN_CHORD_MM:
            out[i] = chord / length
    return out


def surfels_from_columns(cols: dict, pose: Pose = Pose(), table: int = 0,
                         source: str = "<contacts>") -> Surfels:
    """Surfels of one contact table (columns as :func:`camwhisker.files.tables.read_columns` reads).

    Raises
    ------
    ValueError
        The table has no rows.
    """
    n_rows = np.asarray(cols["t_s"]).size
    if n_rows == 0:
        raise TableError(f"{source}: no rows (a header only): nothing to perceive from")
    x_hat, y_hat, sigma_mf = _points(cols)
    keep = _pause_points(x_hat, y_hat)
    pts = np.c_[x_hat[keep], y_hat[keep]]
    dirs = pose.rotate(_directions(pts))
    ray = pts - np.c_[np.asarray(cols["x_mm"], float)[keep], np.zeros(keep.size)]
    ray /= np.maximum(np.hypot(*ray.T), 1e-9)[:, None]
    spread = pose.rotate(np.nan_to_num(sigma_mf[keep])[:, None] * ray)
    x_base = np.asarray(cols["x_mm"], float)
    x_base = np.unique(np.round(x_base[np.isfinite(x_base)]))  # one per mm of travel
    free = pose.apply(np.c_[x_base, np.zeros(x_base.size)])
    return Surfels(pose.apply(pts), dirs, np.ones(keep.size), np.full(keep.size, table), free,
                   spread)


def merge(parts: list[Surfels]) -> Surfels:
    """One surfel set from several tables' (already in the common frame)."""
    return Surfels(*(np.concatenate([getattr(p, f) for p in parts])
                     for f in ("xy_mm", "dir", "belief", "table", "free_xy_mm", "spread")))


def read_surfels(paths: list[str | Path], poses: list[Pose] | None = None) -> Surfels:
    """Surfels of contact tables (docs/sensor.md section 7), each in its pose (default: identity).

    Raises
    ------
    TableError
        A table missing, empty, without a required column, or with a bad cell.
    """
    poses = poses or [Pose()] * len(paths)
    if len(poses) != len(paths):
        raise ValueError(f"give one pose per contact table ({len(paths)} tables, "
                         f"{len(poses)} poses)")
    parts = []
    for i, (path, pose) in enumerate(zip(paths, poses, strict=True)):
        # Only the columns used: a contact table also holds text (doubt).
        cols = read_columns(path, REQUIRED_COLUMNS, OPTIONAL_COLUMNS)
        parts.append(surfels_from_columns(cols, pose, i, str(path)))
    return merge(parts)
