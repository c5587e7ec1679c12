"""The image's blur: measured across straight edges, and given back to warped templates.

A rest template warped to a tilted pose (:func:`~camwhisker.vision.lk.warp_templates`)
carries the rest image's blur warped with it: foreshortened by the affine map A, its
covariance sigma^2 A A^T is narrower than the sigma^2 I of the tilted image itself.
The blurred corner then matches a little inward of where it lies, the more so the
larger the tilt, and the features read smaller: dz low, growing with phi^2.
:func:`reblur_templates` adds the difference, sigma^2 (I - A A^T) (its positive
part), with sigma measured once at rest across the square's edges
(:func:`square_blur_px`). numpy and the standard library only: importing scipy's
special functions and FFT cost a batch ~0.15 s of start-up.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np
from numpy import fft  # imported with the module, not by a live frame's first use

from camwhisker.sensor.model import N_SQUARE

__all__ = [
    "REBLUR_PAD_PX",
    "erf_sigmas",
    "square_blur_px",
    "reblur_templates",
]

#: Half-width (px) of the profiles across the square's edges: 3 sigma of the
#: blurriest webcam, short of the cross's arm ends (12 px inside the edge).
SQUARE_PROFILE_PX = 8.0
PROFILE_STEP_PX = 0.25
#: Where along each edge of the square the profiles lie (fractions of the side):
#: clear of the corners (a spring may end there) and of the cross's arms (0.36-0.64).
SQUARE_PROFILE_AT = np.concatenate([np.linspace(0.12, 0.30, 4), np.linspace(0.70, 0.88, 4)])
#: Soft-L1 scale of that fit, in colour share: noise and ringing of a few per cent count fully.
SHARE_FIT_SCALE = 0.03
#: Levenberg-Marquardt of :func:`erf_sigmas`: a row stops when a step gains less than
#: LM_FTOL of its cost (sigma then within ~2e-5 px of the optimum), or when its damping
#: passes LM_DAMPING_MAX (no step gains any more).
LM_FTOL = 1e-10
LM_DAMPING_START = 1e-3
LM_DAMPING_MAX = 1e12
LM_MAX_ITER = 100
#: Templates are warped this much larger (px) than the LK window, so the added
#: blur's kernel (3 sigma of sigma^2 (1 - cos^2 36 deg) at sigma 2.6: 4.6 px) reads
#: real pixels at the window's edge.
REBLUR_PAD_PX = 5
#: Below this added variance (px^2) in every template, none is reblurred: at rest A is
#: I up to rounding.
MIN_REBLUR_VAR = 1e-6

#: erfc elementwise (the standard library's, to ~1 ulp), for the normal CDF.
_erfc = np.frompyfunc(math.erfc, 1, 1)


def _ndtr(z: np.ndarray) -> np.ndarray:
    """The standard normal CDF of each element: erfc(-z / sqrt 2) / 2, which keeps
    its relative accuracy in both tails."""
    return 0.5 * _erfc(-np.asarray(z, float) / math.sqrt(2.0)).astype(float)


@functools.cache
def _frequencies(n: int) -> tuple[np.ndarray, ...]:
    """Angular frequencies (rad / px) of an n x n real FFT: along u (its last axis,
    halved), along v, shapes (1, n // 2 + 1) and (n, 1); and their squares."""
    ku = (2.0 * np.pi * fft.rfftfreq(n))[None, :]
    kv = (2.0 * np.pi * fft.fftfreq(n))[:, None]
    return ku, kv, ku**2, kv**2


def erf_sigmas(x: np.ndarray, prof: np.ndarray, f_scale: float) -> np.ndarray:
    """Per row of ``prof`` (sampled at ``x``), the Gaussian sigma of a rising blurred
    step a + b Phi((x - x0) / sigma) fitted to it (soft-L1 loss of scale ``f_scale``, the
    profile's units); NaN where the fit's rise b is under that scale (no step above the
    noise), its step is wider than the window, or the row is not finite.

    The rows are independent 4-parameter problems, solved together: Levenberg-Marquardt
    on the loss's reweighted normal equations (its weight 1 / sqrt(1 + (r / f_scale)^2)),
    each row damped and stopped on its own, within the bounds b >= 0, x0 in the window,
    0.05 <= sigma <= 2 x[-1]: small dense systems, where one sparse problem over every
    row pays for its generality.
    """
    prof = np.asarray(prof, float)
    n = prof.shape[0]
    # The start rises, by at least half the loss's scale.
    q = np.column_stack([prof[:, 0], np.maximum(prof[:, -1] - prof[:, 0], 0.5 * f_scale),
                         np.zeros(n), np.ones(n)])  # fmt: skip
    lo = np.array([-np.inf, 0.0, x[0], 0.05])
    hi = np.array([np.inf, np.inf, x[-1], 2.0 * x[-1]])

    def resid(q, p):
        z = (x - q[:, 2:3]) / q[:, 3:4]
        cdf = _ndtr(z)
        return q[:, :1] + q[:, 1:2] * cdf - p, z, cdf

    def cost(r):
        return np.sum(np.sqrt(1.0 + (r / f_scale) ** 2) - 1.0, axis=1)

    finite = np.isfinite(prof).all(axis=1)
    live = np.flatnonzero(finite)
    r, z, cdf = resid(q, prof)
    c, lam = cost(r), np.full(n, LM_DAMPING_START)
    for _ in range(LM_MAX_ITER):
        b, sig, zl, rl = q[live, 1:2], q[live, 3:4], z[live], r[live]
        pdf = np.exp(-0.5 * zl * zl) / math.sqrt(2.0 * math.pi)
        jac = np.stack([np.ones_like(zl), cdf[live], -b * pdf / sig, -b * pdf * zl / sig], -1)
        jw = np.swapaxes(jac / np.sqrt(1.0 + (rl / f_scale) ** 2)[..., None], 1, 2)
        normal = jw @ jac
        diag = np.einsum("nii->ni", normal)
        normal[:, range(4), range(4)] += lam[live, None] * np.maximum(diag, 1e-12)
        q_try = np.clip(q[live] - np.linalg.solve(normal, jw @ rl[..., None])[..., 0], lo, hi)
        r_try, z_try, cdf_try = resid(q_try, prof[live])
        c_try = cost(r_try)
        gain = c[live] - c_try
        better = gain > 0
        done = (better & (gain <= LM_FTOL * c[live])) | (lam[live] > LM_DAMPING_MAX)
        took = live[better]
        for kept, tried in ((q, q_try), (r, r_try), (z, z_try), (cdf, cdf_try), (c, c_try)):
            kept[took] = tried[better]
        lam[live] = np.where(better, lam[live] / 10.0, lam[live] * 10.0)
        live = live[~done]
        if not live.size:
            break
    b, sig = q[:, 1], q[:, 3]
    return np.where(finite & (b > f_scale) & (sig < x[-1]), sig, np.nan)


def square_blur_px(blue: np.ndarray, corners_uv: np.ndarray) -> float:
    """The image's blur (Gaussian sigma, px) across the square's edges in its colour
    share map ``blue``: the median of erf fits to profiles from the cloth into the
    square along each edge, between the corners (4, 2; map pixels, in order around
    the square) and clear of the cross's arms. NaN where no profile fits."""
    c = np.asarray(corners_uv, float)[:N_SQUARE]
    if not np.isfinite(c).all():
        return math.nan
    a, b = c, np.roll(c, -1, axis=0)
    along = (b - a) / np.linalg.norm(b - a, axis=1, keepdims=True)
    normal = along[:, ::-1] * (1.0, -1.0)
    inward = np.sign(np.sum(normal * (c.mean(axis=0) - a), axis=1))[:, None] * normal
    pts = (a[:, None] + SQUARE_PROFILE_AT[None, :, None] * (b - a)[:, None]).reshape(-1, 2)
    inward = np.repeat(inward, len(SQUARE_PROFILE_AT), axis=0)
    x = np.arange(-SQUARE_PROFILE_PX, SQUARE_PROFILE_PX + 1e-9, PROFILE_STEP_PX)
    mx, my = (pts[:, :, None] + inward[:, :, None] * x).transpose(1, 0, 2).astype(np.float32)
    prof = cv2.remap(np.asarray(blue, np.float32), mx, my, cv2.INTER_CUBIC,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)  # fmt: skip
    whole = np.isfinite(prof).all(axis=1)
    if not whole.any():
        return math.nan
    sigma = erf_sigmas(x, prof[whole].astype(float), SHARE_FIT_SCALE)
    return float(np.nanmedian(sigma)) if np.isfinite(sigma).any() else math.nan


def reblur_templates(big: np.ndarray, affine: np.ndarray, sigma_px: float) -> np.ndarray:
    """Warped templates given back the blur their warp took away.

    Parameters
    ----------
    big : ndarray, shape (K, n + 2 REBLUR_PAD_PX, n + 2 REBLUR_PAD_PX), float32
        Templates warped REBLUR_PAD_PX larger on each side than wanted.
    affine : ndarray, shape (K, 2, 2)
        Each template's warp, rest -> current (:func:`~camwhisker.vision.lk.warp_templates`).
    sigma_px : float
        The image's blur; NaN or 0: none added.

    Returns
    -------
    ndarray, shape (K, n, n), float32
        Each template convolved with the Gaussian of covariance the positive part of
        sigma^2 (I - A A^T), cropped to n x n.
    """
    p = REBLUR_PAD_PX
    big = np.asarray(big, np.float32)
    w, v = np.linalg.eigh(sigma_px**2 * (np.eye(2) - affine @ np.swapaxes(affine, 1, 2)))
    if not np.nanmax(w, initial=0.0) > MIN_REBLUR_VAR:  # also a NaN sigma
        return np.ascontiguousarray(big[:, p:-p, p:-p])
    cov = np.einsum("kij,kj,klj->kil", v, np.clip(w, 0.0, None), v)  # (K, 2, 2), (u, v)
    # In the Fourier domain: a Gaussian of any covariance, however thin (a tilt
    # foreshortens one direction only), without sampling its kernel on the pixel grid.
    # The padding takes the transform's wrap-around (3 sigma < REBLUR_PAD_PX).
    n = big.shape[-1]
    ku, kv, ku2, kv2 = _frequencies(n)
    c = cov[:, None, None]
    quad = c[..., 0, 0] * ku2 + 2.0 * c[..., 0, 1] * ku * kv + c[..., 1, 1] * kv2
    quad *= -0.5
    gain = np.exp(quad, out=quad).astype(np.float32)
    # irfft2(rfft2(big) * gain) one axis at a time, as numpy's does it (the same values)
    # without its checks and copies; the last axis's inverse only on the rows kept.
    spectrum = fft.fft(fft.rfft(big, axis=-1), axis=-2)
    spectrum *= gain
    out = fft.irfft(fft.ifft(spectrum, axis=-2)[:, p:-p], n=n, axis=-1)
    return np.ascontiguousarray(out[:, :, p:-p], dtype=np.float32)
