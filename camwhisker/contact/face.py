"""A contact that sticks at an edge, then is dragged along a flat face: r from the travel.

Pressed against a plate's rim or a wall, the whisker first sticks (Coulomb friction): the
contact stays at one point of the object, eq. 8 holds with the travel since first
contact, and the contact keeps its distance y0 along the shaft while the whisker's
deflection there, the travel dx, grows: r = sqrt(y0^2 + dx^2) (:func:`stuck_r`). Per frame,
the fusion weighs GM against MF, whose r is ten to a hundred times noisier; over the
stretch that one stuck contact explains to the front end's noise (:func:`fit_stuck`) r
comes from the stretch instead.

Once the friction gives, the contact is dragged along the face: in the plane of the shaft
and the press, with x the base's travel toward the object and the contact at (x - G(r,
phi), sqrt(r^2 - G^2)) (G the GM model read backwards,
:func:`~camwhisker.contact.gm.deflection_mm`), it runs from the edge (x_e, y0) along a
line at beta to the travel::

    (x - G - x_e) sin(beta) - (sqrt(r^2 - G^2) - y0) cos(beta) = 0

one equation for each frame's r (:func:`face_r`). beta is the face's, one for the contact:
fitted to MF's r over the dragged frames (:func:`fit_face`), where MF's noise averages
out; GM's travel then places each frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from camwhisker.contact.gm import GMFit, deflection_mm
from camwhisker.contact.slide import (
    _OUT_MM,
    _R0_MM,
    FIT_PHI_DEG,
    MAX_RMS_MM,
    MIN_ROWS,
    MIN_SPAN_DEG,
    first_contact_guess,
)

__all__ = ["StuckFit", "fit_stuck", "stuck_y0", "stuck_r", "FaceFit", "fit_face", "face_r",
           "mf_cost", "MAX_FACE_Z"]  # fmt: skip

#: Faces searched (deg from the travel): a coarse grid, then refined around its best.
_BETA_GRID_DEG = np.arange(5.0, 176.0, 1.0)
#: Bisection steps for a frame's r: the bracket's 150 mm to 1e-10 mm.
_BISECT = 40
#: A face is taken where MF's r lies within this of its r in MF's own spread (the median
#: |z| over the dragged frames: 0.04-0.54 on the plates of tuning taps 0-39; 0.67 for
#: noise that MF's spread describes exactly).
MAX_FACE_Z = 1.0


@dataclass(frozen=True)
class StuckFit:
    """A contact's stuck start: one stuck contact over its first ``rows`` fitted rows
    (phi >= :data:`FIT_PHI_DEG`), the last of them at index ``last`` of the rows given."""

    rows: int
    last: int
    rms_mm: float


def _stuck_residual(gm: GMFit, x, phi):
    """Eq. 8 with one r and the first contact x0 fitted to the travel: the residuals (mm).
    The stretch is found from this; r itself comes from GM's rows (:func:`stuck_r`)."""
    from scipy.optimize import least_squares  # ~0.5 s to import; only 3-D tables need it

    start = first_contact_guess(gm, x, phi)

    def residual(p):  # r out of the model's reach: far from any travel, not NaN
        return np.nan_to_num(p[0] + deflection_mm(gm, p[1], phi) - x, nan=_OUT_MM)

    return least_squares(residual, [start, 60.0], bounds=([-np.inf, _R0_MM[0]],
                                                           [np.inf, _R0_MM[1]])).fun


def fit_stuck(gm: GMFit, x_mm, phi_deg) -> StuckFit | None:
    """The longest start of a contact (time order, NaN rows skipped) that one stuck contact
    explains: eq. 8's residual, over the stretch and over its last :data:`MIN_ROWS` rows,
    within :data:`MAX_RMS_MM` (a drag's first rows leave 0.5-1 mm). None where no stretch
    of :data:`MIN_ROWS` rows and :data:`MIN_SPAN_DEG` of phi does."""
    x = np.asarray(x_mm, float)
    phi = np.asarray(phi_deg, float)
    idx = np.flatnonzero(np.isfinite(x) & np.isfinite(phi) & (phi >= FIT_PHI_DEG))
    x, phi = x[idx], phi[idx]

    def rms(k):
        if k < MIN_ROWS or np.ptp(phi[:k]) < MIN_SPAN_DEG:
            return None
        res = _stuck_residual(gm, x[:k], phi[:k])
        whole = float(np.sqrt(np.mean(res ** 2)))
        tail = float(np.sqrt(np.mean(res[-MIN_ROWS:] ** 2)))
        return whole if max(whole, tail) <= MAX_RMS_MM else None

    lo, hi, best = MIN_ROWS, idx.size, None  # a drag once begun stays in every longer stretch
    while lo <= hi:
        k = (lo + hi) // 2
        got = rms(k)
        if got is None:
            hi = k - 1
        else:
            best, lo = (k, got), k + 1
    if best is None:
        return None
    return StuckFit(best[0], int(idx[best[0] - 1]), best[1])


def stuck_y0(r_gm_mm, dx_mm) -> float:
    """A stuck contact's distance along the shaft (mm): the median of GM's over its rows."""
    r, dx = np.asarray(r_gm_mm, float), np.asarray(dx_mm, float)
    return float(np.nanmedian(np.sqrt(r ** 2 - dx ** 2)))


def stuck_r(y0_mm: float, dx_mm) -> np.ndarray:
    """r (mm) of a contact stuck at y0 along the shaft after a travel dx since first contact."""
    return np.sqrt(y0_mm ** 2 + np.asarray(dx_mm, float) ** 2)


@dataclass(frozen=True)
class FaceFit:
    """The face a contact is dragged along: from the edge (x_e_mm on the travel, y0_mm
    along the shaft) at beta_deg to the travel; ``z`` is MF's median |r - face's r| in
    MF's spread over the ``rows`` dragged frames, and ``taken`` whether it is within
    :data:`MAX_FACE_Z`."""

    x_e_mm: float
    y0_mm: float
    beta_deg: float
    z: float
    rows: int
    taken: bool


def face_r(gm: GMFit, x_e_mm: float, y0_mm: float, beta_deg: float, x_mm, phi_deg
           ) -> np.ndarray:  # fmt: skip
    """Each frame's r (mm) on the face: the root of the face's equation between y0/2 and
    the whisker's length, by bisection; NaN where the bracket holds none."""
    x, phi = np.asarray(x_mm, float), np.asarray(phi_deg, float)
    sb, cb = math.sin(math.radians(beta_deg)), math.cos(math.radians(beta_deg))

    def f(r):
        g = deflection_mm(gm, r, phi)
        return (x - g - x_e_mm) * sb - (np.sqrt(np.maximum(r * r - g * g, 0.0)) - y0_mm) * cb

    a = np.full(x.shape, 0.5 * y0_mm)
    b = np.full(x.shape, gm.l_w_mm - 1.0)
    fa = f(a)
    ok = np.sign(fa) * np.sign(f(b)) < 0
    for _ in range(_BISECT):
        m = 0.5 * (a + b)
        fm = f(m)
        left = np.sign(fm) == np.sign(fa)
        a, fa, b = np.where(left, m, a), np.where(left, fm, fa), np.where(left, b, m)
    return np.where(ok, 0.5 * (a + b), np.nan)


def fit_face(gm: GMFit, x_e_mm: float, y0_mm: float, x_mm, phi_deg, r_mf_mm, sigma_mf_mm
             ) -> FaceFit | None:  # fmt: skip
    """The face's beta fitted to MF over a contact's dragged frames (time order): the
    soft-L1 cost of MF's r against the face's in MF's spread, on a grid then refined.
    None where fewer than :data:`MIN_ROWS` frames have phi >= :data:`FIT_PHI_DEG` and MF."""
    from scipy.optimize import minimize_scalar

    x, phi = np.asarray(x_mm, float), np.asarray(phi_deg, float)
    r_mf, s_mf = np.asarray(r_mf_mm, float), np.asarray(sigma_mf_mm, float)
    use = np.isfinite(x) & np.isfinite(phi) & (phi >= FIT_PHI_DEG) & np.isfinite(r_mf) \
        & np.isfinite(s_mf) & (s_mf > 0)
    if use.sum() < MIN_ROWS:
        return None
    x, phi, r_mf, s_mf = x[use], phi[use], r_mf[use], s_mf[use]

    def z(beta_deg):
        return (face_r(gm, x_e_mm, y0_mm, beta_deg, x, phi) - r_mf) / s_mf

    def cost(beta_deg):
        return mf_cost(face_r(gm, x_e_mm, y0_mm, beta_deg, x, phi), r_mf, s_mf)

    b0 = float(_BETA_GRID_DEG[int(np.argmin([cost(b) for b in _BETA_GRID_DEG]))])
    step = float(_BETA_GRID_DEG[1] - _BETA_GRID_DEG[0])
    beta = float(minimize_scalar(cost, bounds=(b0 - step, b0 + step), method="bounded").x)
    med = float(np.nanmedian(np.abs(z(beta))))
    return FaceFit(float(x_e_mm), float(y0_mm), beta, med, int(use.sum()), med <= MAX_FACE_Z)


def mf_cost(r_mm, r_mf_mm, sigma_mf_mm) -> float:
    """How far MF's r lies from ``r_mm`` over a contact's rows: the mean soft-L1 of their
    difference in MF's spread (rows without MF skipped; a row ``r_mm`` misses counts as
    far off). Robust: MF's kNN gives an outlier now and then."""
    r, r_mf, s = (np.asarray(v, float) for v in (r_mm, r_mf_mm, sigma_mf_mm))
    use = np.isfinite(r_mf) & np.isfinite(s) & (s > 0)
    z = np.where(np.isfinite(r[use]), (r[use] - r_mf[use]) / s[use], 1e3)
    return float(np.mean(np.sqrt(1.0 + z * z) - 1.0)) if z.size else math.inf
