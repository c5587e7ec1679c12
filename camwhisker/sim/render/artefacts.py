"""Webcam artefacts, each its own parameter, applied to a noise-free scene.

Order, as in the camera: light falls on the scene (uneven LEDs, vignetting,
flicker, a sudden jump, exposure gain and its drift), the lens blurs (a Gaussian,
or a defocus disc with a halo), the sensor adds signal-dependent noise (per
photosite behind a Bayer filter, then demosaiced) and saturates, the camera
applies its white balance gains (a colour cast that drifts slowly), quantises
to 8 bits and may send chroma at half the horizontal resolution (4:2:2).
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
    #: The lens's point spread: "gaussian" (sigma ``blur_sigma_px``) or "defocus": a
    #: uniform disc of the same variance (radius 2 sigma) with HALO_SHARE of the light
    #: spread HALO_SCALE times wider (veiling glare).
    psf: str = "gaussian"
    #: A colour sensor behind a Bayer filter (RGGB): one colour per photosite, the
    #: noise added there, then demosaiced (OpenCV's edge-aware method).
    bayer: bool = False
    #: Chroma sent at half the horizontal resolution (YUYV 4:2:2, as UVC cameras send).
    chroma_422: bool = False
    #: Auto-exposure's slow drift: relative amplitude and period (s) of the gain.
    exposure_drift: float = 0.0
    exposure_drift_period_s: float = 7.0


#: Share of the light and relative width of the "defocus" lens's halo.
HALO_SHARE = 0.06
HALO_SCALE = 4.0


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
    if art.exposure_drift:
        phase = 2 * math.pi * t_s / art.exposure_drift_period_s
        light *= 1.0 + art.exposure_drift * math.sin(phase)
    if illumination is None:
        illumination = illumination_field(scene.shape[:2], art)
    img = scene * (illumination * np.float32(light))[..., None]
    if art.blur_sigma_px > 0:
        img = _lens(img, art)
    if art.bayer:
        img = _mosaic(img)[..., None]  # one channel: the photosites
    if art.noise_dn > 0:
        var = art.noise_dn**2 * (
            art.read_noise_fraction + (1 - art.read_noise_fraction) * np.maximum(img, 0) / 128.0
        )
        img = img + np.sqrt(var) * rng.standard_normal(img.shape, dtype=np.float32)
    if art.bayer:
        raw = np.clip(np.rint(img[..., 0]), 0, 255).astype(np.uint8)
        # OpenCV names a Bayer pattern by its second row's second and third sites: BG is RGGB.
        img = cv2.cvtColor(raw, cv2.COLOR_BayerBG2BGR_EA).astype(np.float32)
    drift = art.cast_drift * math.sin(2 * math.pi * t_s / art.cast_drift_period_s)
    gains = np.array(art.cast_bgr, np.float32) * np.array([1 + drift, 1.0, 1 - drift], np.float32)
    img = img * gains
    out = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    return _chroma_422(out) if art.chroma_422 else out


def _lens(img: np.ndarray, art: Artefacts) -> np.ndarray:
    """The lens's blur: a Gaussian, or a defocus disc of the same variance with a halo."""
    sigma = art.blur_sigma_px
    if art.psf == "gaussian":
        return cv2.GaussianBlur(img, (0, 0), sigma)
    if art.psf != "defocus":
        raise ValueError(f"unknown psf {art.psf!r}: gaussian or defocus")
    r = 2.0 * sigma  # a disc of radius r has variance r^2 / 4 per axis
    n = int(math.ceil(r)) + 1
    sub = 8  # the disc's edge drawn 8x finer, then averaged onto the pixel grid
    y, x = (np.mgrid[-n * sub : (n + 1) * sub, -n * sub : (n + 1) * sub] + 0.5) / sub - 0.5
    disc = (x * x + y * y <= r * r).astype(np.float32)
    disc = disc.reshape(2 * n + 1, sub, 2 * n + 1, sub).mean(axis=(1, 3))
    disc /= disc.sum()
    core = cv2.filter2D(img, -1, disc, borderType=cv2.BORDER_REFLECT)
    halo = cv2.GaussianBlur(img, (0, 0), HALO_SCALE * sigma)
    return (1.0 - HALO_SHARE) * core + HALO_SHARE * halo


def _mosaic(img: np.ndarray) -> np.ndarray:
    """The RGGB Bayer mosaic of a BGR image: each photosite keeps its filter's colour."""
    raw = img[..., 1].copy()  # green on the two diagonal sites
    raw[0::2, 0::2] = img[0::2, 0::2, 2]  # red
    raw[1::2, 1::2] = img[1::2, 1::2, 0]  # blue
    return raw


def _chroma_422(bgr: np.ndarray) -> np.ndarray:
    """The frame as YUYV carries it: luma per pixel, chroma averaged over pixel pairs."""
    ycc = cv2.cvtColor(bgr, cv2.COLOR_BGR2YCrCb).astype(np.float32)
    w = ycc.shape[1] - ycc.shape[1] % 2
    pairs = 0.5 * (ycc[:, 0:w:2, 1:] + ycc[:, 1:w:2, 1:])
    ycc[:, 0:w:2, 1:] = pairs
    ycc[:, 1:w:2, 1:] = pairs
    return cv2.cvtColor(np.clip(np.rint(ycc), 0, 255).astype(np.uint8), cv2.COLOR_YCrCb2BGR)


def jpeg_roundtrip(frame: np.ndarray, quality: int) -> np.ndarray:
    """Compress and decompress one frame as a webcam's MJPG stream would."""
    ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return cv2.imdecode(buf, cv2.IMREAD_COLOR)
