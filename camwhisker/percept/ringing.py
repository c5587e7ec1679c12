"""The whisker's free ringing: its natural frequency and damping from a recording's tail.

After the whisker leaves a surface it rings in its first mode. The frequency is
found as the peak of the tail's spectrum (FFT, Hann window, zero-padded) and
refined with the damping ratio by a least-squares damped cosine,

    u(t) = c + A exp(-zeta w (t - t0)) cos(w sqrt(1 - zeta^2) (t - t0) + psi),

whose covariance gives their standard errors (the method of the base-stress /
side-strain whisker study, ../shared/seeds/003: FFT of the free ringing).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Ringing", "RingingError", "fit_ringing", "mode_gain"]

# Below this the tail's slow drift, not the mode, fills the spectrum.
MIN_RING_HZ = 0.5
# Zero-padding of the tail's FFT: the peak is found to 1/8 of a bin before the fit.
_PAD = 8


class RingingError(ValueError):
    """No free ringing could be fitted in the given stretch."""


@dataclass(frozen=True)
class Ringing:
    natural_hz: float
    natural_se_hz: float
    damping: float
    damping_se: float


def fit_ringing(t_s, u, source: str = "<signals>") -> Ringing:
    """Natural frequency and damping ratio of a free decay (arrays, shape (N,), no NaN)."""
    from scipy.optimize import curve_fit

    t = np.asarray(t_s, float) - t_s[0]
    x = np.asarray(u, float) - np.mean(u)
    fs = 1.0 / np.median(np.diff(t))
    n = _PAD * t.size
    spec = np.abs(np.fft.rfft(x * np.hanning(t.size), n))
    freq = np.fft.rfftfreq(n, 1.0 / fs)
    band = freq >= MIN_RING_HZ
    if t.size < 8 or not band.any():
        raise RingingError(f"{source}: the free ringing is too short to analyse "
                           f"({t.size} rows)")
    f0 = float(freq[band][np.argmax(spec[band])])

    def decay(tt, c, a, psi, f, zeta):
        w = 2.0 * math.pi * f
        return c + a * np.exp(-zeta * w * tt) * np.cos(w * np.sqrt(1.0 - zeta**2) * tt + psi)

    start = (0.0, float(np.max(np.abs(x))), 0.0, f0, 0.05)
    bounds = ([-np.inf, 0.0, -np.inf, 0.5 * f0, 0.0], [np.inf, np.inf, np.inf, 2.0 * f0, 0.9])
    best = None
    for psi in np.linspace(-math.pi, math.pi, 4, endpoint=False):  # the fit's phase is multimodal
        try:
            p, cov = curve_fit(decay, t, x, p0=(*start[:2], psi, *start[3:]), bounds=bounds)
        except RuntimeError:
            continue
        cost = float(np.sum((decay(t, *p) - x) ** 2))
        if best is None or cost < best[0]:
            best = (cost, p, cov)
    if best is None or not np.all(np.isfinite(best[2])):
        raise RingingError(f"{source}: no damped oscillation fits the free ringing "
                           f"(its spectrum peaks at {f0:.2f} Hz)")
    _, p, cov = best
    se = np.sqrt(np.diag(cov))
    return Ringing(float(p[3]), float(se[3]), float(p[4]), float(se[4]))


def mode_gain(f_hz, ringing: Ringing):
    """|H(f)| of the first mode, H = w^2 / (w^2 - (2 pi f)^2 + 2 i zeta w 2 pi f)."""
    r = np.asarray(f_hz, float) / ringing.natural_hz
    return 1.0 / np.sqrt((1.0 - r * r) ** 2 + (2.0 * ringing.damping * r) ** 2)
