"""A contact that slides along a smooth object: r over a whole contact from the base's travel.

Eq. 8 assumes the contact sticks. On a smooth convex object (a sphere, a cylinder across the
shaft) the point of tangency slides toward the base as the whisker bends, up to several mm
of r per mm of press, and GM's r from the travel since first contact runs far from it.

In the plane of the shaft and the press, with the base at the origin and x its travel toward
the object, the contact at r sits at -G(r, phi) across the shaft, G the GM model read
backwards (:func:`~camwhisker.contact.gm.deflection_mm`), and y = sqrt(r^2 - G^2) along the
shaft (r is the contact's distance from the base). In the object's frame it sits at
(x - G, y) and moves along the whisker's tangent there, at s(r, phi) to the shaft::

    dx = dG(r, phi) - tan(s(r, phi)) dy

With r linear in phi over the contact, r = r0 + a phi, and x0 the travel at first contact,
the three are fitted to the travel by least squares (:func:`fit_slide`), beside a contact
at one r (a = 0: on the simulator's rigid pegs and sphere taps, taking y as r instead
leaves r 0.3-2.4 mm long). The slide is taken where it explains the travel clearly
better, toward the base (a < 0), and to the front end's noise.

s is the bent whisker's slope at the load: the base's tilt phi plus the bending's, which for
a cantilever loaded at r is 3/2 of its deflection there over r.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from camwhisker.contact.gm import GMFit, deflection_mm

__all__ = ["FIT_PHI_DEG", "MIN_ROWS", "MIN_RATIO", "MAX_RMS_MM", "SlideFit", "fit_slide"]

#: Rows fitted: the contact's rows with phi at least this (deg); under it G is noise.
FIT_PHI_DEG = 1.0
#: Least rows and phi span (deg) for a fit: three parameters need a press, not a pause.
MIN_ROWS = 20
MIN_SPAN_DEG = 2.0
#: The slide is taken where one r's RMS travel residual is at least this many times the
#: slide's (tuning taps, seeds 0-39: spheres 2.3-10.8, all a < 0; plates 1.0-1.2) ...
MIN_RATIO = 1.5
#: ... and the slide's residual (mm) is the front end's (0.04-0.08 on the taps of the
#: tuning seeds; a stick-slip the model cannot follow leaves 1-5 mm).
MAX_RMS_MM = 0.15
#: A residual under this (mm) is exact for the ratio: noise-free travel fits both alike.
_EXACT_MM = 0.01
#: Bounds on r0 (mm) and a (mm of r per deg of phi) for the solver.
_R0_MM = (5.0, 150.0)
_A_MM_PER_DEG = (-20.0, 20.0)
#: The residual (mm) of a row whose r leaves the GM model's range.
_OUT_MM = 1e3


@dataclass(frozen=True)
class SlideFit:
    """A contact's fitted slide: r = r0_mm + a_mm_per_deg phi, the RMS travel residuals
    (mm) of the slide and of a contact at one r, and whether the slide is taken."""

    r0_mm: float
    a_mm_per_deg: float
    rms_mm: float
    one_r_rms_mm: float
    taken: bool

    def r_mm(self, phi_deg) -> np.ndarray:
        return self.r0_mm + self.a_mm_per_deg * np.asarray(phi_deg, float)


def _slope(gm: GMFit, r, phi_deg):
    """The whisker's slope (rad) at a load at r: the tilt plus 3/2 of the bending over r."""
    ph = np.radians(phi_deg)
    bend = deflection_mm(gm, r, phi_deg) - r * np.sin(ph)
    return ph + 1.5 * bend / r


def _travel(gm: GMFit, x0, r0, a, phi):
    """x = x0 + G(r, phi) - integral of tan(s) dy along the contact's rows (trapezoid)."""
    r = r0 + a * phi
    g = deflection_mm(gm, r, phi)
    t = np.tan(_slope(gm, r, phi))
    dy = np.diff(np.sqrt(r ** 2 - g ** 2))
    return x0 + g - np.concatenate(([0.0], np.cumsum(0.5 * (t[1:] + t[:-1]) * dy)))


def first_contact_guess(gm: GMFit, x, phi) -> float:
    """A starting x0 (mm) for a fit to the travel: the first row's less a contact at 60 mm's
    deflection, or the first row's travel where that is out of the model's reach."""
    start = float(x[0] - deflection_mm(gm, 60.0, phi[0]))
    return start if math.isfinite(start) else float(x[0])


def fit_slide(gm: GMFit, x_mm, phi_deg) -> SlideFit | None:
    """The slide and a contact at one r fitted to one contact's rows (time order, NaN rows
    skipped); None where too few rows with phi >= :data:`FIT_PHI_DEG` or too little phi span.
    ``x_mm`` is the base's travel toward the object (the contact table's ``x_mm`` along the
    travel's sign)."""
    from scipy.optimize import least_squares  # ~0.5 s to import; only 3-D tables need it

    x = np.asarray(x_mm, float)
    phi = np.asarray(phi_deg, float)
    use = np.isfinite(x) & np.isfinite(phi) & (phi >= FIT_PHI_DEG)
    if use.sum() < MIN_ROWS or np.ptp(phi[use]) < MIN_SPAN_DEG:
        return None
    x, phi = x[use], phi[use]
    start = first_contact_guess(gm, x, phi)

    def residual(p):  # r out of the model's reach: far from any travel, not NaN
        return np.nan_to_num(_travel(gm, p[0], p[1], p[2] if p.size > 2 else 0.0, phi) - x,
                             nan=_OUT_MM)

    one = least_squares(residual, [start, 60.0], bounds=([-np.inf, _R0_MM[0]],
                                                           [np.inf, _R0_MM[1]]))
    slide = least_squares(residual, [one.x[0], one.x[1], 0.0],
                          bounds=([-np.inf, _R0_MM[0], _A_MM_PER_DEG[0]],
                                  [np.inf, _R0_MM[1], _A_MM_PER_DEG[1]]))  # fmt: skip
    rms = float(np.sqrt(np.mean(slide.fun ** 2)))
    one_rms = float(np.sqrt(np.mean(one.fun ** 2)))
    a = float(slide.x[2])
    taken = bool(a < 0.0 and rms <= MAX_RMS_MM and one_rms >= MIN_RATIO * max(rms, _EXACT_MM))
    return SlideFit(float(slide.x[1]), a, rms, one_rms, taken)
