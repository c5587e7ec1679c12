"""Z-dissimilarity, eq. (11), its combined-spread variant, spread tables and score metrics.

Eq. (11) divides the signed GM - MF difference by sigma_GM(phi) only. MF is
far noisier than GM, so that score flags good GM estimates whenever MF is off
(the paper reports 26 % false flags). :func:`z_combined` divides by the
spread of the difference itself, sqrt(sigma_GM^2 + sigma_MF^2).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "PHI_BIN_EDGES_DEG",
    "SpreadTable",
    "spread_table",
    "z_dissimilarity",
    "z_combined",
    "roc_auc",
    "flag_rates",
]

# Table II's phi bins (deg): < 2.5, < 5, < 10, < 20, taken as disjoint ranges,
# plus >= 20 for the rest.
PHI_BIN_EDGES_DEG = (0.0, 2.5, 5.0, 10.0, 20.0, np.inf)
# A bin needs this many errors for its own mean and spread; smaller bins take
# the pooled values (a spread from fewer points is itself too uncertain).
MIN_BIN_SAMPLES = 5


@dataclass(frozen=True)
class SpreadTable:
    """Mean and standard deviation of an error r - r_hat per phi bin (arrays shape (B,))."""

    edges_deg: np.ndarray
    n: np.ndarray
    mean_mm: np.ndarray
    std_mm: np.ndarray

    def sigma_at(self, phi_deg) -> np.ndarray:
        """The spread for each phi; NaN for NaN phi."""
        phi = np.asarray(phi_deg, float)
        if phi.size == 1:  # the live loop's one row: a look-up in Python
            v = phi.item()
            k = min(max(bisect.bisect_right(self.edges_deg, v) - 1, 0), self.std_mm.size - 1)
            return np.full(phi.shape, self.std_mm[k] if math.isfinite(v) else np.nan)
        at = np.where(np.isnan(phi), 0.0, phi)  # np.nan_to_num is slow in the live loop
        # np.minimum(np.maximum()) is np.clip without its slow Python wrapper (the live loop).
        k = np.minimum(np.maximum(np.searchsorted(self.edges_deg, at, side="right") - 1, 0),
                       self.std_mm.size - 1)
        return np.where(np.isfinite(phi), self.std_mm[k], np.nan)

    def rows(self):
        """(lo, hi, n, mean, std) per bin, for printing."""
        return list(zip(self.edges_deg[:-1], self.edges_deg[1:], self.n, self.mean_mm,
                        self.std_mm, strict=True))


def spread_table(phi_deg, err_mm, edges_deg=PHI_BIN_EDGES_DEG) -> SpreadTable:
    """Per-bin mean and sample standard deviation of the finite errors."""
    edges = np.asarray(edges_deg, float)
    phi = np.asarray(phi_deg, float).ravel()
    err = np.asarray(err_mm, float).ravel()
    keep = np.isfinite(phi) & np.isfinite(err)
    phi, err = phi[keep], err[keep]
    if err.size < 2:
        raise ValueError(f"a spread table needs at least 2 finite errors, got {err.size}")
    pooled_mean, pooled_std = float(err.mean()), float(err.std(ddof=1))
    nb = edges.size - 1
    n, mean, std = np.zeros(nb, int), np.full(nb, pooled_mean), np.full(nb, pooled_std)
    k = np.searchsorted(edges, phi, side="right") - 1
    for b in range(nb):
        e = err[k == b]
        n[b] = e.size
        if e.size >= MIN_BIN_SAMPLES:
            mean[b], std[b] = e.mean(), e.std(ddof=1)
    return SpreadTable(edges, n, mean, std)


def z_dissimilarity(r_gm_mm, r_mf_mm, sigma_gm_mm):
    """Z = (r_GM - r_MF) / sigma_GM(phi); NaN where any input is undefined or sigma <= 0."""
    r_gm = np.asarray(r_gm_mm, float)
    r_mf = np.asarray(r_mf_mm, float)
    sigma = np.asarray(sigma_gm_mm, float)
    if r_gm.size == 1 and r_gm.shape == r_mf.shape == sigma.shape:  # one live row, in floats
        d, s = r_gm.item() - r_mf.item(), sigma.item()
        return np.full(r_gm.shape, d / s if math.isfinite(d) and math.isfinite(s) and s > 0
                       else np.nan)  # Eq. (11)
    diff = r_gm - r_mf
    ok = np.isfinite(diff) & np.isfinite(sigma) & (sigma > 0)
    return np.divide(diff, sigma, out=np.full(np.broadcast(diff, sigma).shape, np.nan),
                     where=ok)  # Eq. (11)


def z_combined(r_gm_mm, r_mf_mm, sigma_gm_mm, sigma_mf_mm):
    """(r_GM - r_MF) / sqrt(sigma_GM^2 + sigma_MF^2): the difference in units of its own spread."""
    spread = np.hypot(np.asarray(sigma_gm_mm, float), np.asarray(sigma_mf_mm, float))
    return z_dissimilarity(r_gm_mm, r_mf_mm, spread)


def roc_auc(score, positive) -> float:
    """Area under the ROC curve of ``score`` for the boolean ``positive`` (ties count half).

    Mann-Whitney form over finite scores; NaN if either class is empty.
    """
    s = np.asarray(score, float)
    p = np.asarray(positive, bool)
    keep = np.isfinite(s)
    s, p = s[keep], p[keep]
    n_pos, n_neg = int(p.sum()), int((~p).sum())
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    order = np.argsort(s, kind="mergesort")
    ranks = np.empty(s.size)
    sorted_s = s[order]
    # Average ranks over ties.
    _, first, counts = np.unique(sorted_s, return_index=True, return_counts=True)
    avg = first + (counts - 1) / 2.0 + 1.0
    ranks[order] = np.repeat(avg, counts)
    return float((ranks[p].sum() - n_pos * (n_pos + 1) / 2.0) / (n_pos * n_neg))


def flag_rates(score, positive, threshold: float = 1.0):
    """(hit rate, false-flag rate): share of positives / negatives with score > threshold.

    Samples with an undefined score are left out.
    """
    s = np.asarray(score, float)
    p = np.asarray(positive, bool)
    keep = np.isfinite(s)
    s, p = s[keep], p[keep]
    hit = float(np.mean(s[p] > threshold)) if p.any() else float("nan")
    false = float(np.mean(s[~p] > threshold)) if (~p).any() else float("nan")
    return hit, false
