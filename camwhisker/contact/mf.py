"""Moment-Force (MF) estimate of the radial contact distance, eqs. (9)-(10).

A k-nearest-neighbour look-up (k = 7) in a table of (phi, dz, r) from
calibration runs, over the normalised coordinates (phi / 35 deg, dz / 1 mm),
weighted by inverse distance.

Eq. (9) as printed is a signed sum, d_k = (phi - phi_k)/35 + (dz - dz_k)/1,
which can be zero or negative for points far away; we use the Euclidean
distance over the same normalised coordinates instead.

Defined outputs for degenerate cases:

- a query that coincides with one or more table points (distance 0) returns
  the mean r of those points (the limit of eq. (10));
- duplicate table points are fine (they are separate neighbours);
- a table with fewer than k rows uses all rows;
- NaN inputs, or phi below :data:`~camwhisker.contact.gm.PHI_MIN_DEG`, give NaN;
- a query farther than :data:`MF_DOMAIN_RADIUS` from every table point is
  outside the table's domain: NaN and ``outside = True``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from camwhisker.contact.gm import PHI_MIN_DEG

__all__ = ["MF_K", "PHI_SCALE_DEG", "DZ_SCALE_MM", "MF_DOMAIN_RADIUS", "MFTable", "MFResult",
           "r_mf"]

MF_K = 7  # the paper's k
PHI_SCALE_DEG = 35.0  # Eq. (9): the largest expected phi
DZ_SCALE_MM = 1.0  # Eq. (9): the largest expected dz
# Normalised distance beyond which a query has no table support: 0.1 is
# 3.5 deg or 0.1 mm, more than the widest phi spacing of a calibration run
# (about 2.5 deg per 1 mm step at r = 22.5 mm) plus its noise.
MF_DOMAIN_RADIUS = 0.1


@dataclass(frozen=True)
class MFTable:
    """Labelled calibration points, arrays shape (N,), and a k-d tree over eq. (9)'s axes."""

    phi_deg: np.ndarray
    dz_mm: np.ndarray
    r_mm: np.ndarray
    tree: cKDTree = field(repr=False, compare=False, default=None)

    @classmethod
    def build(cls, phi_deg, dz_mm, r_mm) -> MFTable:
        """Keep the finite rows with phi >= PHI_MIN_DEG; raise ValueError if none remain."""
        phi = np.asarray(phi_deg, float).ravel()
        dz = np.asarray(dz_mm, float).ravel()
        r = np.asarray(r_mm, float).ravel()
        keep = np.isfinite(phi) & np.isfinite(dz) & np.isfinite(r) & (phi >= PHI_MIN_DEG)
        if not keep.any():
            raise ValueError("MF table needs at least one row with finite phi >= "
                             f"{PHI_MIN_DEG} deg, dz and r")
        phi, dz, r = phi[keep], dz[keep], r[keep]
        return cls(phi, dz, r, cKDTree(_coords(phi, dz)))

    def __len__(self) -> int:
        return self.r_mm.size


def _coords(phi_deg, dz_mm):
    return np.column_stack([np.asarray(phi_deg, float) / PHI_SCALE_DEG,
                            np.asarray(dz_mm, float) / DZ_SCALE_MM])


@dataclass(frozen=True)
class MFResult:
    """r_MF (NaN where undefined), the out-of-domain flag and the nearest distance."""

    r_mm: np.ndarray
    outside: np.ndarray
    nearest: np.ndarray


def r_mf(table: MFTable, phi_deg, dz_mm, k: int = MF_K, exclude_self: bool = False,
         domain_radius: float = MF_DOMAIN_RADIUS) -> MFResult:
    """Inverse-distance-weighted kNN estimate of r, eqs. (9)-(10).

    Parameters
    ----------
    table : MFTable
    phi_deg, dz_mm : array_like, shape (N,)
    k : int
        Neighbours (the paper: 7); fewer if the table is smaller.
    exclude_self : bool
        Leave-one-out: the queries are the table's own rows (in order) and each
        row is left out of its own estimate. For the spread sigma_MF.
    """
    phi = np.atleast_1d(np.asarray(phi_deg, float))
    dz = np.atleast_1d(np.asarray(dz_mm, float))
    phi, dz = np.broadcast_arrays(phi, dz)
    n = phi.size
    r_out = np.full(n, np.nan)
    outside = np.zeros(n, bool)
    nearest = np.full(n, np.nan)
    valid = np.isfinite(phi) & np.isfinite(dz) & (phi >= PHI_MIN_DEG)
    extra = 1 if exclude_self else 0
    kk = min(k + extra, len(table))
    if not valid.any() or kk - extra < 1:
        return MFResult(r_out, outside, nearest)
    d, j = table.tree.query(_coords(phi[valid], dz[valid]), k=kk)  # Eq. (9), Euclidean
    d = d.reshape(-1, kk)
    j = j.reshape(-1, kk)
    if exclude_self:
        own = np.flatnonzero(valid)[:, None]
        not_self = j != own
        # Drop the query's own row (or the last neighbour if it was not among them).
        order = np.argsort(~not_self, axis=1, kind="stable")[:, : kk - 1]
        d = np.take_along_axis(d, order, axis=1)
        j = np.take_along_axis(j, order, axis=1)
    labels = table.r_mm[j]
    exact = d == 0.0
    any_exact = exact.any(axis=1)
    w = np.divide(1.0, d, out=np.zeros_like(d), where=~exact)
    w = np.where(any_exact[:, None], exact.astype(float), w)
    est = np.sum(w * labels, axis=1) / np.sum(w, axis=1)  # Eq. (10)
    near = d[:, 0]
    out = near > domain_radius
    r_out[valid] = np.where(out, np.nan, est)
    outside[valid] = out
    nearest[valid] = near
    return MFResult(r_out, outside, nearest)
