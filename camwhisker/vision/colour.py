"""White balance from the white cloth, and the red/blue contrast map of eq. (1).

White balance is gray-world over a fixed sparse set of cloth pixels outside
the feature region: the cloth is white and the springs are neutral grey, so
the mean of each channel over those pixels should be equal. The gains undo a
colour cast and follow its slow drift frame by frame, or can be locked to the
rest frame's. Uneven lighting and vignetting scale the three channels alike
and do not bias the gains.

The contrast map of eq. (1) is a ratio, so it does not depend on the
brightness of the light either: with P the pixel mean (R + G + B) / 3,
G = ((B - P) - (R - P)) / P is about +1.4 on the blue square, -1.6 on the red
cross and 0 on the white cloth, the grey springs and the black tip.

References
----------
.. [1] Weinkauf et al., "Identifying Contact Distance Uncertainty in Whisker
   Sensing with Tapered, Flexible Whiskers", section II.A.2, eq. (1).
"""

from __future__ import annotations

import cv2
import numpy as np

from camwhisker.kernels import colour as kernels

__all__ = [
    "cloth_samples",
    "white_balance_gains",
    "contrast_map",
    "apply_gains",
    "unmixing_weights",
    "unmixed_maps",
    "share_patches",
    "cloth_level",
]

#: Spacing (px) of the cloth sample grid: 3600 points on a 1280 x 720 frame, of
#: which those beyond the rod's reach (the frame's corners) are kept.
CLOTH_GRID_PX = 16
#: Fewest cloth samples: where the rod's reach covers more of the frame (a longer
#: rod, a longer focal length), the grid points farthest from the centre are kept.
CLOTH_MIN_SAMPLES = 21

#: Samples darker than this fraction of the median cloth level, or with a channel
#: saturated at 255, are left out of the gray-world mean (shadows, the rod, clipping).
CLOTH_MIN_FRACTION = 0.5
SATURATED_DN = 254

_TINY = float(np.finfo(np.float32).tiny)


def cloth_samples(
    shape: tuple[int, int],
    exclude_center_uv: np.ndarray,
    exclude_radius_px: float,
    grid_px: int = CLOTH_GRID_PX,
) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of a sparse grid of cloth pixels outside a disc.

    Parameters
    ----------
    shape : (int, int)
        Image (height, width).
    exclude_center_uv : ndarray, shape (2,)
        Centre (u, v) of the feature region, which holds no cloth.
    exclude_radius_px : float
        Radius of the feature region: as far as the magnifier tip can reach.
        Where it leaves fewer than CLOTH_MIN_SAMPLES grid points, the
        CLOTH_MIN_SAMPLES farthest from the centre are taken.

    Returns
    -------
    rows, cols : ndarray, shape (N,)
        Integer pixel indices of the samples.
    """
    h, w = shape
    v, u = np.mgrid[grid_px // 2 : h : grid_px, grid_px // 2 : w : grid_px]
    v, u = v.ravel(), u.ravel()
    dist = np.hypot(u - exclude_center_uv[0], v - exclude_center_uv[1])
    keep = dist > exclude_radius_px
    if keep.sum() < CLOTH_MIN_SAMPLES:
        keep = np.zeros(dist.size, bool)
        keep[np.argsort(dist, kind="stable")[-CLOTH_MIN_SAMPLES:]] = True
    return v[keep], u[keep]


def white_balance_gains(frame: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Gray-world gains (B, G, R) from cloth samples; the gains have mean 1.

    Parameters
    ----------
    frame : ndarray, shape (H, W, 3), uint8 or float
        BGR image; not modified.
    rows, cols : ndarray, shape (N,)
        Cloth sample pixels, from :func:`cloth_samples`.

    Returns
    -------
    gains : ndarray, shape (3,), float32
        Multiply channel c by gains[c] to balance it. All ones when no usable
        sample is left (e.g. a black frame).
    """
    rows, cols = np.asarray(rows, np.intp), np.asarray(cols, np.intp)
    return kernels.gray_world(np.asarray(frame), rows, cols, CLOTH_MIN_FRACTION, SATURATED_DN)


def apply_gains(bgr: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """A white-balanced float32 copy of a BGR image or region, shape (h, w, 3)."""
    out = bgr.astype(np.float32)
    out *= np.asarray(gains, np.float32)
    return out


def contrast_map(bgr: np.ndarray, gains: np.ndarray | None = None) -> np.ndarray:
    """Red/blue contrast G of eq. (1) for every pixel of an image or region.

    Parameters
    ----------
    bgr : ndarray, shape (h, w, 3), uint8 or float
        BGR pixels (a region of interest, to keep it cheap); not modified.
    gains : ndarray, shape (3,), optional
        White-balance gains (B, G, R) applied first.

    Returns
    -------
    g : ndarray, shape (h, w), float32
        G = ((B - P) - (R - P)) / P with P = (R + G + B) / 3; G = 0 where P = 0.
    """
    gb, gg, gr = (1.0, 1.0, 1.0) if gains is None else (float(x) for x in gains)
    b, g, r = cv2.split(np.asarray(bgr))
    f32 = cv2.CV_32F
    # (B - P) - (R - P) = B - R; OpenCV, not numpy: faster on strided channel views.
    b_minus_r = cv2.addWeighted(b, gb, r, -gr, 0.0, dtype=f32)
    p = cv2.addWeighted(b, gb / 3.0, g, gg / 3.0, 0.0, dtype=f32)
    p = cv2.scaleAdd(r.astype(np.float32), gr / 3.0, p)
    # P = 0 only on a black pixel, where B - R = 0 too: 0 / tiny gives G = 0 there.
    return cv2.divide(b_minus_r, cv2.max(p, _TINY))  # Eq. (1)


def unmixing_weights(red_bgr, blue_bgr, cloth_bgr) -> np.ndarray:
    """Linear weights that read a pixel as its share of red and of blue.

    Solves, for each feature colour, a weight vector w with w . red = 1 (or 0),
    w . blue = 0 (or 1) and w . cloth = 0. A pixel that mixes colours (an edge
    blurred by the lens) then reads exactly its mixing fraction, whatever lies
    on the other side of the edge. Eq. (1) divides by each pixel's own mean P,
    which bends that fraction and moves an edge by up to ~0.7 px depending on
    whether blue or white cloth lies behind it; the pixel-wise ratio is kept for
    detection, these weights serve the sub-pixel steps.

    Parameters
    ----------
    red_bgr, blue_bgr, cloth_bgr : array_like, shape (3,)
        White-balanced colours of the cross, the square and the cloth (DN).

    Returns
    -------
    weights : ndarray, shape (2, 3)
        Row 0 gives the red share, row 1 the blue share, from (B, G, R).

    Raises
    ------
    ValueError
        When the three colours are linearly dependent (no contrast).
    """
    c = np.array([red_bgr, blue_bgr, cloth_bgr], dtype=float)
    if abs(np.linalg.det(c)) < 1e-6 * np.abs(c).max() ** 3:
        raise ValueError("feature colours are not distinguishable (singular colour matrix)")
    return np.linalg.solve(c, np.eye(3)[:, :2]).T


def unmixed_maps(bgr: np.ndarray, weights: np.ndarray, gains=None, scale: float = 1.0):
    """Red share and blue share of each pixel, float32, each shape (h, w).

    ``gains`` are folded into the weights; ``scale`` divides the result (the
    light level now relative to the frame the colours were measured in).
    """
    gains = np.ones(3) if gains is None else np.asarray(gains, float)
    w = np.asarray(weights, float) * gains[None, :] / scale
    b, g, r = cv2.split(np.asarray(bgr))
    f32 = cv2.CV_32F
    rf = r.astype(np.float32)
    out = []
    for row in w:
        m = cv2.addWeighted(b, float(row[0]), g, float(row[1]), 0.0, dtype=f32)
        out.append(cv2.scaleAdd(rf, float(row[2]), m))
    return out[0], out[1]


def share_patches(frame: np.ndarray, top_left: np.ndarray, size: int, weights: np.ndarray):
    """Square patches of one colour share each, shape (K, size, size), float32.

    Patch k is ``frame[v:v + size, u:u + size] @ weights[k]`` with (u, v) =
    ``top_left[k]`` (integer, inside the frame): a row of :func:`unmixing_weights`
    with the gains and light level folded in, as :func:`unmixed_maps` uses them.
    """
    return kernels.share_patches(np.ascontiguousarray(frame), np.asarray(top_left, np.intp), size,
                                 np.asarray(weights, np.float32))  # fmt: skip


def cloth_level(frame: np.ndarray, rows: np.ndarray, cols: np.ndarray, gains) -> float:
    """Mean white-balanced brightness (B + G + R) / 3 of the cloth samples (DN)."""
    rows, cols = np.asarray(rows, np.intp), np.asarray(cols, np.intp)
    return kernels.cloth_level(np.asarray(frame), rows, cols, np.asarray(gains, np.float32))
