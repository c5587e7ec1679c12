"""The rest reference: what the front end measures once, at the rest frame.

:class:`RestReference` holds it, frozen: the white-balance gains, the points'
offsets from the plate model, the rest points, the colour-share maps the
corners' templates are warped from, the unmixing weights, the cloth level and
the paper's rest widths. A rezero builds a new one.

The helpers here average the rest frames, place the corners' region and
measure the rest colours.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from camwhisker.vision.colour import cloth_level, unmixing_weights
from camwhisker.vision.detect import FeaturesNotFound
from camwhisker.vision.paper import PaperRest

__all__ = ["RestReference", "mean_image", "region_size", "region_origin", "colour_core",
           "rest_colours"]

#: Margin of the corners' region beyond their window (px): room for the
#: templates' warps and for the rest colours' samples.
REGION_MARGIN_PX = 40
#: The corners' spread grows by up to ~8% (dz = 1 mm brings them 4% closer; a tilt
#: spreads the near side): the region is this much larger than at rest.
REGION_GROWTH = 1.15
#: Rest-frame colours are medians over pixels with |G| above this, eroded by
#: COLOUR_ERODE_PX so that no blurred edge pixel enters.
COLOUR_G_MIN = 1.0
COLOUR_ERODE_PX = 4
#: A colour fainter than COLOUR_G_MIN (white balance on tinted cloth pales the
#: cross) takes the pixels within this share of its extreme (99th percentile) instead;
#: one whose extreme is under COLOUR_FAINTEST is not there.
COLOUR_CORE_SHARE = 0.8
COLOUR_FAINTEST = 0.5
#: Fewest pixels of a colour for its median to be trusted.
COLOUR_MIN_PX = 10


@dataclass(frozen=True)
class RestReference:
    """The rest frame's measurements, built once by :meth:`FrontEnd.start`.

    Attributes
    ----------
    gains : ndarray, shape (3,)
        White-balance gains (B, G, R) of the rest frame.
    uv : ndarray, shape (13, 2)
        The rest points (square corners, cross arm-end corners, tip), px.
    offsets : ndarray, shape (13, 2)
        Rest points minus the plate model's points at pose zero (px).
    origin : ndarray, shape (2,)
        Pixel (u, v) of the corners' region's top-left corner.
    region_size : tuple of int
        (width, height) of that region (px).
    red, blue : ndarray, shape (height, width), float32
        Red-share (cross) and blue-share (square) maps over the region: the
        corners' first templates.
    weights : ndarray, shape (2, 3)
        Unmixing weights of the red and blue shares.
    cloth_level : float
        Mean white-balanced cloth brightness (DN).
    paper : PaperRest
        The rest widths and tip of eqs. (2)-(4).
    share_blur_px : float
        The blur of the colour shares across the square's edges (Gaussian sigma,
        px; :func:`~camwhisker.vision.blur.square_blur_px`), which the warped
        templates are given back; NaN where it was not measured.
    tip_blur_px : float
        The blur of the luma across the tip's edge (px;
        :func:`~camwhisker.vision.tip.edge_blur_px`), which moves the edge inward
        (:func:`~camwhisker.vision.tip.blurred_rim`); NaN where not measured.
    """

    gains: np.ndarray
    uv: np.ndarray
    offsets: np.ndarray
    origin: np.ndarray
    region_size: tuple[int, int]
    red: np.ndarray
    blue: np.ndarray
    weights: np.ndarray
    cloth_level: float
    paper: PaperRest
    share_blur_px: float
    tip_blur_px: float


def mean_image(images: list[np.ndarray]) -> np.ndarray:
    """The pixelwise mean of frames at rest, float32 (same shape): the rest frame
    whose noise is the frames' own over sqrt(len(images)). Not rounded: rounding
    to whole DN would add 0.29 DN of noise, more than 30 frames of 1 DN leave."""
    total = np.zeros(images[0].shape, np.float32)
    for image in images:
        total += image
    return total / np.float32(len(images))


def region_size(frame_shape, uv: np.ndarray, half_px: int) -> tuple[int, int]:
    """(width, height) of a region holding the points ``uv`` (N, 2) as they spread
    while the plate moves, with room for windows of ``half_px``; at most the frame."""
    h, w = frame_shape[:2]
    ok = np.isfinite(uv).all(axis=1)
    ext = uv[ok].max(axis=0) - uv[ok].min(axis=0)
    margin = half_px + REGION_MARGIN_PX
    size = np.ceil(ext * REGION_GROWTH).astype(int) + 2 * margin
    return min(int(size[0]), w), min(int(size[1]), h)


def region_origin(frame_shape, uv: np.ndarray, size: tuple[int, int]) -> np.ndarray | None:
    """Top-left pixel (u, v) of a region of ``size`` centred on the points, shape (2,),
    kept inside the frame; None when no point is finite."""
    h, w = frame_shape[:2]
    ok = np.isfinite(uv).all(axis=1)
    if not ok.any():
        return None
    rw, rh = size
    c = (uv[ok].min(axis=0) + uv[ok].max(axis=0)) / 2
    u0 = int(np.clip(round(c[0] - rw / 2), 0, w - rw))
    v0 = int(np.clip(round(c[1] - rh / 2), 0, h - rh))
    return np.array([u0, v0], float)


def colour_core(g: np.ndarray) -> np.ndarray:
    """Pixels well inside the colour whose contrast ``g`` (eq. 1, signed so that it
    is positive) is high: above COLOUR_G_MIN or COLOUR_CORE_SHARE of its extreme,
    whichever is lower, and eroded by COLOUR_ERODE_PX; bool, shape of ``g``."""
    extreme = float(np.percentile(g, 99))
    if extreme < COLOUR_FAINTEST:
        return np.zeros(g.shape, bool)
    threshold = min(COLOUR_G_MIN, COLOUR_CORE_SHARE * extreme)
    kernel = np.ones((2 * COLOUR_ERODE_PX + 1,) * 2, np.uint8)
    return cv2.erode((g > threshold).astype(np.uint8), kernel).astype(bool)


def rest_colours(frame, gains, g, origin, cloth_rows, cloth_cols) -> tuple[np.ndarray, float]:
    """Unmixing weights from the colours of cross, square and cloth, and the cloth level.

    Parameters
    ----------
    frame : ndarray, shape (H, W, 3), uint8
    gains : ndarray, shape (3,)
    g : ndarray, shape (h, w)
        Contrast map of eq. (1) over the region at ``origin``.
    origin : ndarray, shape (2,)
    cloth_rows, cloth_cols : ndarray
        The cloth's sample pixels.

    Raises
    ------
    FeaturesNotFound
        Too few pixels of the cross's or the square's colour.
    """
    u0, v0 = origin.astype(int)
    h, w = g.shape
    region = frame[v0 : v0 + h, u0 : u0 + w].astype(np.float32) * gains
    red, blue = colour_core(-g), colour_core(g)
    if red.sum() < COLOUR_MIN_PX or blue.sum() < COLOUR_MIN_PX:
        raise FeaturesNotFound(["square colour" if blue.sum() < COLOUR_MIN_PX else "cross colour"])
    cloth = (frame[cloth_rows, cloth_cols].astype(np.float32) * gains).mean(axis=0)
    weights = unmixing_weights(np.median(region[red], axis=0), np.median(region[blue], axis=0),
                               cloth)  # fmt: skip
    return weights, cloth_level(frame, cloth_rows, cloth_cols, gains)
