"""Webcam artefacts, each its own parameter, applied to a noise-free scene.

Order, as in the camera: light falls on the scene (uneven LEDs, vignetting,
flicker, a sudden jump, exposure gain), the lens blurs (defocus), the sensor
adds signal-dependent noise and saturates, the camera applies its white
balance gains (a colour cast that drifts slowly) and quantises to 8 bits.
JPEG compression is the video codec's job (:mod:`camwhisker.sim.render.video`), or
:func:`jpeg_roundtrip` for frames kept in memory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["Artefacts", "illumination_field", "apply_artefacts", "jpeg_roundtrip"]


@dataclass(frozen=True)
class Artefacts:
    """Webcam artefacts. All zero/one: a perfect camera."""

    #: Relative strength of the six LED hot spots around the frame.
    unevenness: float = 0.0
    #: Relative fall-off of brightness at the frame corners.
    vignetting: float = 0.0
    #: Camera white-balance gains (B, G, R): a colour cast when unequal.
    cast_bgr: tuple[float, float, float] = (1.0, 1.0, 1.0)
    #: Relative amplitude and period of a slow drift of the cast (B and R in opposition).
    cast_drift: float = 0.0
    cast_drift_period_s: float = 20.0
    #: Frame-to-frame brightness flicker, uniform in [-flicker, +flicker].
    flicker: float = 0.0
    #: Exposure gain; above ~1.1 the cloth saturates.
    gain: float = 1.0
    #: A sudden lighting change: (time in s, factor from then on), or None.
    lighting_jump: tuple[float, float] | None = None
    #: Defocus blur, Gaussian sigma in pixels.
    blur_sigma_px: float = 0.0
    #: Noise standard deviation (DN) at mid grey (128 DN).
    noise_dn: float = 0.0
    #: Fraction of the mid-grey noise variance that is signal-independent (read noise);
    #: the rest grows with the signal (shot noise).
    read_noise_fraction: float = 0.3
    #: JPEG quality of the codec (MJPG AVI), or None for no compression.
    jpeg_quality: int | None = None
    #: H.264 constant rate factor for MP4 files: 18 is visually lossless and keeps
    #: the sensor noise; higher values smooth it away and shrink the file.
    h264_crf: int = 18


def illumination_field(shape: tuple[int, int], art: Artefacts) -> np.ndarray:
    """Static relative illumination, float32, shape (height, width): LEDs and vignetting."""
    h, w = shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    cu, cv = (w - 1) / 2, (h - 1) / 2
    r2 = ((u - cu) ** 2 + (v - cv) ** 2) / (cu**2 + cv**2)
    field = 1.0 - art.vignetting * r2
    if art.unevenness:
        spots = np.zeros_like(field)
        for k in range(6):  # six LEDs on a ring around the lens
            a = 2 * math.pi * k / 6 + 0.3
            pu, pv = cu + 0.42 * w * math.cos(a), cv + 0.42 * h * math.sin(a)
            spots += np.exp(-((u - pu) ** 2 + (v - pv) ** 2) / (2 * (0.18 * w) ** 2))
        field *= 1.0 + art.unevenness * (spots / spots.max() - 0.5)
    return field


def apply_artefacts(
    scene: np.ndarray,
    t_s: float,
    art: Artefacts,
    rng: np.random.Generator,
    illumination: np.ndarray | None = None,
) -> np.ndarray:
    """The frame the camera delivers (before compression), uint8 BGR.

    Parameters
    ----------
    scene : ndarray, shape (H, W, 3), float32
        Noise-free geometry from :class:`~camwhisker.sim.render.render.SceneRenderer`.
        Not modified.
    t_s : float
        Frame time, for the cast drift and the lighting jump.
    illumination : ndarray, shape (H, W), optional
        Precomputed :func:`illumination_field` (computed if omitted).
    """
    light = art.gain * (1.0 + art.flicker * rng.uniform(-1.0, 1.0))
    if art.lighting_jump is not None and t_s >= art.lighting_jump[0]:
        light *= art.lighting_jump[1]
    if illumination is None:
        illumination = illumination_field(scene.shape[:2], art)
    img = scene * (illumination * np.float32(light))[..., None]
    if art.blur_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), art.blur_sigma_px)
    if art.noise_dn > 0:
        var = art.noise_dn**2 * (
            art.read_noise_fraction + (1 - art.read_noise_fraction) * np.maximum(img, 0) / 128.0
        )
        img = img + np.sqrt(var) * rng.standard_normal(img.shape, dtype=np.float32)
    drift = art.cast_drift * math.sin(2 * math.pi * t_s / art.cast_drift_period_s)
    gains = np.array(art.cast_bgr, np.float32) * np.array([1 + drift, 1.0, 1 - drift], np.float32)
    img = img * gains
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def jpeg_roundtrip(frame: np.ndarray, quality: int) -> np.ndarray:
    """Compress and decompress one frame as a webcam's MJPG stream would."""
    ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return cv2.imdecode(buf, cv2.IMREAD_COLOR)
