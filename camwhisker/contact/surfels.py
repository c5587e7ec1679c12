"""Surfels from contact tables: a point, a direction along the surface and a belief.

A surfel (BIOTACT, eqs. 1-2) is what one contact says about the object: the
contact point (eq. 12's x_hat, y_hat), a direction parallel to the surface
there and the belief that the contact happened. Here

- the point is the contact table's (x_hat_mm, y_hat_mm), one per stage pause
  (the table repeats a pause's estimate on each of its frames);
- the direction is that of the chord between the neighbouring contacts of the
  same table (central difference), left undefined (NaN) where they lie closer
  than :data:`MIN_CHORD_MM` (a stuck contact says nothing about the surface);
- the belief is 1 for a row with a contact estimate (r_hat defined: the stage
  has travelled past the contact onset) and 0 for the whisker's base, where no
  object can be. Z (eq. 11) is not used: it measures how far GM and MF
  disagree, which the fused r_hat has already settled (a slipping contact has
  Z of 20-140 with its fused point within a millimetre of the surface).

Each table may carry a pose: its stage frame (x along the travel, y along the
whisker's rest axis) placed in a common frame by an origin and a rotation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camwhisker.tables import TableError, read_columns

__all__ = ["Pose", "Surfels", "surfels_from_columns", "read_surfels", "merge", "MIN_CHORD_MM",
           "REQUIRED_COLUMNS"]

# Neighbouring contacts closer than this give no direction: it is the
# contact points' own scatter (fused r_hat, ~0.2-0.3 mm) times a few.
MIN_CHORD_MM = 0.8
#: What a contact table must have (docs/sensor.md section 7).
REQUIRED_COLUMNS = ("t_s", "x_mm", "phi_deg", "x_hat_mm", "r_hat_mm")


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
    table : shape (N,), which input each came from; free_xy_mm : shape (M, 2).
    """

    xy_mm: np.ndarray
    dir: np.ndarray
    belief: np.ndarray
    table: np.ndarray
    free_xy_mm: np.ndarray

    @property
    def n(self) -> int:
        return int(self.xy_mm.shape[0])


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
    """Surfels of one contact table (columns as read by :func:`camwhisker.tables.read_columns`).

    Raises
    ------
    ValueError
        The table has no rows.
    """
    n_rows = np.asarray(cols["t_s"]).size
    if n_rows == 0:
        raise TableError(f"{source}: no rows (a header only): nothing to perceive from")
    x_hat = np.asarray(cols["x_hat_mm"], float)
    if "y_hat_mm" in cols:
        y_hat = np.asarray(cols["y_hat_mm"], float)
    else:  # Eq. (12): y along the rest axis
        y_hat = np.asarray(cols["r_hat_mm"], float) * np.cos(np.radians(cols["phi_deg"]))
    keep = _pause_points(x_hat, y_hat)
    xy = pose.apply(np.c_[x_hat[keep], y_hat[keep]])
    dirs = pose.rotate(_directions(np.c_[x_hat[keep], y_hat[keep]]))
    x_base = np.asarray(cols["x_mm"], float)
    x_base = np.unique(np.round(x_base[np.isfinite(x_base)]))  # one per mm of travel
    free = pose.apply(np.c_[x_base, np.zeros(x_base.size)])
    return Surfels(xy, dirs, np.ones(keep.size), np.full(keep.size, table), free)


def merge(parts: list[Surfels]) -> Surfels:
    """One surfel set from several tables' (already in the common frame)."""
    return Surfels(*(np.concatenate([getattr(p, f) for p in parts])
                     for f in ("xy_mm", "dir", "belief", "table", "free_xy_mm")))


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
        cols = read_columns(path, REQUIRED_COLUMNS)
        try:
            cols.update(read_columns(path, ("y_hat_mm",)))
        except TableError:
            pass  # optional: y_hat from r_hat and phi (eq. 12)
        parts.append(surfels_from_columns(cols, pose, i, str(path)))
    return merge(parts)
