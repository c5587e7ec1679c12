"""Shape reconstruction from the contact distance, eq. (12), on the whisker bent as calibrated."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from camwhisker.contact.gm import GMFit, deflection_mm

__all__ = ["BendCorrection", "fit_bend_correction", "reconstruct", "SURFACE_PHI_POWERS",
           "SURFACE_R_POWERS"]

# Powers of phi and r in the correction surfaces. The GM model's error grows with the bend,
# which is second order and up in phi and vanishes at phi 0; along r it is smooth.
SURFACE_PHI_POWERS = (2, 3, 4)
SURFACE_R_POWERS = (0, 1, 2, 3)
# Samples per coefficient below which no correction is fitted: eq. 12 keeps the GM model's
# bend alone rather than surfaces the calibration's noise shaped.
MIN_SAMPLES_PER_TERM = 5


@dataclass(frozen=True)
class BendCorrection:
    """What the GM model, read backwards, misses of the bent whisker behind eq. 12.

    Two surfaces, each sum c[i, j] (phi / phi_max)^p_i (r / r_max)^q_j with
    p = :data:`SURFACE_PHI_POWERS`, q = the first ``coef.shape[1]`` of
    :data:`SURFACE_R_POWERS`, evaluated with phi and r clipped to the calibrated box, where a
    polynomial holds; calling it gives both:

    - the offset (``offset_coef``): added to the model's offset of the contact from the
      base's line;
    - the shortening (``shortening_coef``): taken off sqrt(r^2 - d^2), the arc of length r
      taken as its chord; the bent arc's chord is shorter.
    """

    offset_coef: np.ndarray  # shape (len(SURFACE_PHI_POWERS), n_r_powers)
    shortening_coef: np.ndarray  # the same shape
    phi_max_deg: float
    r_min_mm: float
    r_max_mm: float
    # Residual sd (mm) on the calibration without and with each surface, for the record.
    offset_sd_mm: tuple = (np.nan, np.nan)
    shortening_sd_mm: tuple = (np.nan, np.nan)

    def __call__(self, r_mm, phi_deg) -> tuple[np.ndarray, np.ndarray]:
        """(offset, shortening) at r and phi, from one set of terms."""
        # np.minimum(np.maximum()) is np.clip (NaN too) without its slow Python wrapper.
        terms = _design(np.minimum(np.abs(phi_deg), self.phi_max_deg),
                        np.minimum(np.maximum(r_mm, self.r_min_mm), self.r_max_mm),
                        self.phi_max_deg, self.r_max_mm, self.offset_coef.shape[1])
        return terms @ self.offset_coef.ravel(), terms @ self.shortening_coef.ravel()


def _design(phi_deg, r_mm, phi_max_deg, r_max_mm, n_r):
    p, r = np.asarray(phi_deg, float), np.asarray(r_mm, float)
    if p.shape != r.shape:
        p, r = np.broadcast_arrays(p, r)
    p, r = p[..., None] / phi_max_deg, r[..., None] / r_max_mm
    # Each power once, then every product p^i r^j (i outer) in one broadcast multiply.
    pp = np.concatenate([p**i for i in SURFACE_PHI_POWERS], axis=-1)
    rr = np.concatenate([r**j for j in SURFACE_R_POWERS[:n_r]], axis=-1)
    return (pp[..., :, None] * rr[..., None, :]).reshape(*pp.shape[:-1],
                                                         pp.shape[-1] * rr.shape[-1])


def fit_bend_correction(gm: GMFit, dx_mm, phi_deg, r_mm, dz_mm, run) -> BendCorrection | None:
    """Least-squares :class:`BendCorrection` from calibration pauses at known r.

    A calibration peg is thin and does not slide: a contact's offset from the base's line
    is the base's travel dx since the onset, and its height is one per run (``run``: run id
    per pause), which the shortening's fit takes as a free constant per run. r's powers stop
    one short of the number of distinct radii (a cubic needs four). None where the data
    cannot carry even the lowest surfaces.
    """
    dx, phi, r, dz, run = (np.asarray(v).ravel() for v in (dx_mm, phi_deg, r_mm, dz_mm, run))
    phi, r = np.abs(phi.astype(float)), r.astype(float)
    miss = dx - deflection_mm(gm, r, phi)
    ok = np.isfinite(miss) & np.isfinite(phi) & np.isfinite(r) & np.isfinite(dz)
    miss, phi, r, dz, run = miss[ok], phi[ok], r[ok], dz[ok], run[ok]
    runs = np.unique(run)
    n_r = min(len(SURFACE_R_POWERS), np.unique(np.round(r)).size - 1)
    terms = len(SURFACE_PHI_POWERS) * n_r
    if n_r < 1 or miss.size < MIN_SAMPLES_PER_TERM * (2 * terms + runs.size):
        return None
    box = (float(phi.max()), float(r.min()), float(r.max()))
    a = _design(phi, r, box[0], box[2], n_r)
    offset = np.linalg.lstsq(a, miss, rcond=None)[0]
    d = dx[ok] - miss + a @ offset  # eq. 12's offset, as reconstruct has it
    height = np.sqrt(r * r - d * d) - dz
    run_of = np.searchsorted(runs, run)
    per_run = np.eye(runs.size)[run_of]
    design = np.c_[a, per_run]
    sol = np.linalg.lstsq(design, height, rcond=None)[0]
    run_mean = np.bincount(run_of, height) / np.bincount(run_of)
    shape = (len(SURFACE_PHI_POWERS), n_r)
    return BendCorrection(
        offset.reshape(shape), sol[:terms].reshape(shape), *box,
        offset_sd_mm=(float(np.std(miss)), float(np.std(miss - a @ offset))),
        shortening_sd_mm=(float(np.std(height - run_mean[run_of])),
                          float(np.std(height - design @ sol))))


def reconstruct(x_mm, r_hat_mm, phi_deg, dz_mm, travel_sign, gm: GMFit | None = None,
                bend: BendCorrection | None = None):
    """Contact point (x_hat, y_hat) from the base position, r_hat, phi and dz.

    The whisker lags behind the base, so the contact lies behind it along the
    direction of travel by its lateral offset d: x_hat = x - sign(travel) d
    (eq. (12), the sign from the travel). Eq. (12) takes the whisker straight at
    phi: d = r_hat sin(phi), y_hat = r_hat cos(phi) along the rest axis. With the
    calibration's GM model ``gm`` it is bent as that model has it: d is the travel
    after which a stuck contact at r_hat tilts the base by phi (the model read
    backwards, :func:`~camwhisker.contact.gm.deflection_mm`), larger than r sin(phi)
    by the bending, and y_hat = sqrt(r_hat^2 - d^2) (the arc taken as its chord), both
    corrected by the calibration's ``bend`` where there is one. y_hat is measured from the
    base's rest position: the plate, pushed dz toward the camera, takes the base with it, so
    the contact lies dz nearer: y_hat = ... - dz.

    Parameters
    ----------
    x_mm, r_hat_mm, phi_deg, dz_mm : array_like, shape (N,)
    travel_sign : float or array_like
        +1 for travel toward +x, -1 toward -x.
    gm : GMFit, optional
    bend : BendCorrection, optional
        Used only with ``gm``.

    Returns
    -------
    x_hat_mm, y_hat_mm : ndarray
        NaN where any input is NaN, or where the model puts the contact farther off the
        base's line than r_hat (r_hat outside its range).
    """
    phi = np.asarray(phi_deg, float)
    r = np.asarray(r_hat_mm, float)
    if gm is None:
        rad = np.radians(phi)
        d, y = r * np.sin(rad), r * np.cos(rad)
    else:
        offset, shortening = (0.0, 0.0) if bend is None else bend(r, phi)
        d = deflection_mm(gm, r, phi) + offset
        d = np.where(d <= r, d, np.nan)  # an offset past the whisker's length: no point
        y = np.sqrt(r * r - d * d) - shortening
    # Eq. (12)
    return np.asarray(x_mm, float) - np.sign(travel_sign) * d, y - np.asarray(dz_mm, float)
