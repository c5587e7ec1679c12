"""Translation-only Lucas-Kanade on small patches, vectorised over the tracked points.

Two steps per frame, after Matthews, Ishikawa & Baker (2004), "The template
update problem":

1. :func:`track_updated` follows each point from the previous frame with
   OpenCV's pyramidal LK (the template is the previous frame: the updated
   template), with a forward-backward check.
2. :func:`refine_first_template` corrects the result against the first
   template, the rest frame's patch, so errors do not accumulate (drift
   correction). The rest patch is first warped by the affine map the plate
   model predicts between the rest pose and the current pose, so the
   remaining motion is a pure translation even at large tilts.

References
----------
.. [1] I. Matthews, T. Ishikawa, S. Baker, "The template update problem",
   IEEE TPAMI 26(6), 2004. doi:10.1109/TPAMI.2004.16
.. [2] S. Baker, I. Matthews, "Lucas-Kanade 20 years on: a unifying
   framework", IJCV 56(3), 2004. doi:10.1023/B:VISI.0000011205.11775.fd
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = [
    "PATCH_HALF_PX",
    "warp_templates",
    "refine_first_template",
    "match_parabolic",
    "parabolic_peak",
    "track_updated",
    "to_uint8",
]

#: Half size of the LK window (px): 25 x 25 covers a corner's two edges out to
#: > 3 blur sigma (2.6 px in the hard scene) with room to spare, and stays clear
#: of the neighbouring features (the square's edge is 12 px beyond an arm's end,
#: but it lies in the other polarity of the contrast map).
PATCH_HALF_PX = 12
#: Inverse-compositional iterations stop when the step is below this (px): well
#: under a corner's ~0.05 px noise (the iteration converges by ~5x per step, so
#: ~2e-3 px remain); 0.003 px gave the same benchmark errors, 15% slower.
LK_STEP_TOL_PX = 0.01
LK_MAX_ITER = 20
#: Scale of the contrast map into 8 bits for OpenCV's LK: G in [-2, 2] -> [8, 248].
UINT8_SCALE = 60.0


def to_uint8(g: np.ndarray) -> np.ndarray:
    """Contrast map G to uint8 (128 + 60 G, clipped) for OpenCV's pyramidal LK."""
    # +0.5 then truncation: rounding to nearest.
    return np.clip(g * UINT8_SCALE + 128.5, 0.0, 255.0).astype(np.uint8)


def warp_templates(
    rest_map: np.ndarray,
    rest_origin: np.ndarray,
    rest_uv: np.ndarray,
    affine: np.ndarray,
    half: int = PATCH_HALF_PX,
) -> np.ndarray:
    """Rest patches warped into the current frame's shape.

    Parameters
    ----------
    rest_map : ndarray, shape (h, w), float32
        Contrast map of the rest frame over a region.
    rest_origin : ndarray, shape (2,)
        Pixel (u, v) of ``rest_map[0, 0]``.
    rest_uv : ndarray, shape (K, 2)
        Rest positions of the points.
    affine : ndarray, shape (K, 2, 2)
        Linear part A of the map rest -> current around each point.
    half : int

    Returns
    -------
    templates : ndarray, shape (K, 2 half + 1, 2 half + 1), float32
        ``templates[k][y, x]`` is the rest map at rest_uv[k] + A^-1 ((x, y) - half).
    """
    n = 2 * half + 1
    g = np.arange(n, dtype=float) - half
    gx, gy = np.meshgrid(g, g)
    grid = np.stack([gx.ravel(), gy.ravel()])  # (2, n*n)
    inv = np.linalg.inv(affine)  # (K, 2, 2)
    pos = np.einsum("kij,jm->kim", inv, grid) + (rest_uv - rest_origin)[:, :, None]
    # Exact bilinear interpolation in float64, the same weights getRectSubPix uses,
    # so that an unmoved frame reproduces its template exactly (cv2.warpAffine
    # rounds the weights to 1/32 px).
    h, w = rest_map.shape
    x = np.clip(pos[:, 0], 0.0, w - 1.000001)
    y = np.clip(pos[:, 1], 0.0, h - 1.000001)
    x0 = np.floor(x).astype(np.intp)
    y0 = np.floor(y).astype(np.intp)
    fx, fy = x - x0, y - y0
    m = rest_map
    top = m[y0, x0] * (1 - fx) + m[y0, x0 + 1] * fx
    bottom = m[y0 + 1, x0] * (1 - fx) + m[y0 + 1, x0 + 1] * fx
    out = top * (1 - fy) + bottom * fy
    return out.reshape(len(rest_uv), n, n).astype(np.float32)


def refine_first_template(
    image: np.ndarray,
    origin: np.ndarray,
    templates: np.ndarray,
    start_uv: np.ndarray,
    active: np.ndarray,
):
    """Inverse-compositional translation LK of each template in ``image``.

    Intensities are compared after removing each patch's mean, so a uniform
    change of contrast offset does not move the estimate.

    Parameters
    ----------
    image : ndarray, shape (h, w) or (K, h, w), float32
        Current map over a region, or one region per point; ``origin``, shape
        (2,) or (K, 2), is the frame pixel of each region's [0, 0].
    templates : ndarray, shape (K, n, n), float32
        From :func:`warp_templates`; the template centre is the point.
    start_uv : ndarray, shape (K, 2)
        Starting positions (pixels of the full frame).
    active : ndarray of bool, shape (K,)
        Points to refine; the others come back NaN.

    Returns
    -------
    uv : ndarray, shape (K, 2)
        Refined positions (NaN where inactive, diverged or out of the region).
    quality : ndarray, shape (K,)
        Zero-mean normalised cross-correlation of the template and the final
        patch, in [-1, 1]; NaN where there is none.
    """
    k_all, n, _ = templates.shape
    m = n - 2
    uv = np.full((k_all, 2), np.nan)
    quality = np.full(k_all, np.nan)
    t_in = templates[:, 1:-1, 1:-1].astype(np.float64)
    tx = (templates[:, 1:-1, 2:] - templates[:, 1:-1, :-2]).astype(np.float64) * 0.5
    ty = (templates[:, 2:, 1:-1] - templates[:, :-2, 1:-1]).astype(np.float64) * 0.5
    hxx = (tx * tx).sum(axis=(1, 2))
    hxy = (tx * ty).sum(axis=(1, 2))
    hyy = (ty * ty).sum(axis=(1, 2))
    det = hxx * hyy - hxy * hxy
    ok = np.asarray(active, bool) & (det > 1e-12) & np.isfinite(start_uv).all(axis=1)
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        return uv, quality
    stack = image.ndim == 3
    h, w = image.shape[-2:]
    flat = np.ascontiguousarray(image).ravel()
    which = (idx if stack else np.zeros(len(idx), np.intp)) * (h * w)
    origins = np.broadcast_to(np.asarray(origin, float), (k_all, 2))[idx]
    d = (start_uv[idx] - origins).astype(np.float64)  # patch centres, region pixels
    half = (m - 1) / 2
    g = np.arange(m) - int(half)
    grid = (g[:, None] * w + g[None, :]).ravel()  # flat offsets of the window
    tx, ty, t_in = tx[idx].reshape(len(idx), -1), ty[idx].reshape(len(idx), -1), t_in[idx]
    t_in = t_in.reshape(len(idx), -1)
    hxx, hxy, hyy, det = hxx[idx], hxy[idx], hyy[idx], det[idx]
    alive = np.ones(len(idx), bool)
    patch = np.zeros_like(t_in)

    def sample(sel):
        ix = np.floor(d[sel, 0]).astype(np.intp)
        iy = np.floor(d[sel, 1]).astype(np.intp)
        fx = (d[sel, 0] - ix)[:, None]
        fy = (d[sel, 1] - iy)[:, None]
        base = (which[sel] + iy * w + ix)[:, None] + grid
        top = flat[base] * (1 - fx) + flat[base + 1] * fx
        bottom = flat[base + w] * (1 - fx) + flat[base + (w + 1)] * fx
        return top * (1 - fy) + bottom * fy

    lo, hi_x, hi_y = half + 1, w - 2 - half, h - 2 - half
    for _ in range(LK_MAX_ITER):
        alive &= (d[:, 0] >= lo) & (d[:, 0] <= hi_x) & (d[:, 1] >= lo) & (d[:, 1] <= hi_y)
        if not alive.any():
            break
        patch[alive] = sample(alive)
        e = patch - t_in
        e -= e.mean(axis=1, keepdims=True)
        bx = (tx * e).sum(axis=1)
        by = (ty * e).sum(axis=1)
        step = np.column_stack([(hyy * bx - hxy * by) / det, (hxx * by - hxy * bx) / det])
        step[~alive] = 0.0
        d -= step
        if np.abs(step).max() < LK_STEP_TOL_PX:
            break
    alive &= (d[:, 0] >= lo) & (d[:, 0] <= hi_x) & (d[:, 1] >= lo) & (d[:, 1] <= hi_y)
    if not alive.any():
        return uv, quality
    p = sample(alive)
    pz = p - p.mean(axis=1, keepdims=True)
    tz = t_in[alive] - t_in[alive].mean(axis=1, keepdims=True)
    den = np.sqrt((pz * pz).sum(axis=1) * (tz * tz).sum(axis=1))
    with np.errstate(invalid="ignore", divide="ignore"):
        quality[idx[alive]] = np.where(den > 0, (pz * tz).sum(axis=1) / den, np.nan)
    uv[idx[alive]] = d[alive] + origins[alive]
    return uv, quality


def parabolic_peak(score: np.ndarray) -> tuple[float, float, float]:
    """Sub-pixel (x, y) and value of the maximum of a 2-D score map.

    A parabola through the peak and its two neighbours along each axis; the
    integer peak where it lies on the border."""
    _, top, _, (x, y) = cv2.minMaxLoc(score)
    dx = dy = 0.0
    if 0 < x < score.shape[1] - 1:
        a, b, c = score[y, x - 1], score[y, x], score[y, x + 1]
        den = a - 2 * b + c
        dx = 0.5 * (a - c) / den if den < 0 else 0.0
    if 0 < y < score.shape[0] - 1:
        a, b, c = score[y - 1, x], score[y, x], score[y + 1, x]
        den = a - 2 * b + c
        dy = 0.5 * (a - c) / den if den < 0 else 0.0
    return x + dx, y + dy, float(top)


def match_parabolic(
    image: np.ndarray,
    origin: np.ndarray,
    templates: np.ndarray,
    start_uv: np.ndarray,
    active: np.ndarray,
):
    """Each template's best match in its region: NCC (cv2.matchTemplate) and a parabolic peak.

    The alternative to :func:`refine_first_template` (same arguments and
    returns; ``image`` holds one region per point, shape (K, h, w)). The whole
    region is searched, so ``start_uv`` only says which points have one.
    Quality is the peak's zero-mean normalised cross-correlation.
    """
    k_all = templates.shape[0]
    uv = np.full((k_all, 2), np.nan)
    quality = np.full(k_all, np.nan)
    window = np.ascontiguousarray(templates[:, 1:-1, 1:-1], np.float32)  # as the LK's
    half = (window.shape[1] - 1) / 2
    origins = np.broadcast_to(np.asarray(origin, float), (k_all, 2))
    for k in np.flatnonzero(np.asarray(active, bool) & np.isfinite(start_uv).all(axis=1)):
        if not window[k].std() > 0:
            continue
        score = cv2.matchTemplate(np.ascontiguousarray(image[k], np.float32), window[k],
                                  cv2.TM_CCOEFF_NORMED)  # fmt: skip
        x, y, top = parabolic_peak(score)
        uv[k] = origins[k] + (x + half, y + half)
        quality[k] = top
    return uv, quality


#: Pyramidal LK for the updated-template step: levels and window cover motions of
#: ~ (2^3) * 12 = 100 px between frames (a jump between two stage holds).
PYR_LEVELS = 3
_PYR_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)


def track_updated(prev_u8: np.ndarray, prev_origin, prev_uv, cur_u8, cur_origin, guess_uv,
                  half: int = PATCH_HALF_PX, levels: int = PYR_LEVELS):  # fmt: skip
    """Pyramidal LK from the previous frame, with a forward-backward check.

    Parameters
    ----------
    prev_u8, cur_u8 : ndarray, shape (h, w), uint8
        Contrast maps (see :func:`to_uint8`) of the previous and current frame
        over regions whose top-left pixels are ``prev_origin`` and ``cur_origin``.
    prev_uv : ndarray, shape (K, 2)
        Positions in the previous frame.
    guess_uv : ndarray, shape (K, 2)
        Expected positions in the current frame (a motion prediction).
    half, levels : int
        Window (2 half + 1 px square) and pyramid levels of cv2.calcOpticalFlowPyrLK.

    Returns
    -------
    uv : ndarray, shape (K, 2)
        Tracked positions, NaN where LK failed.
    fb_px : ndarray, shape (K,)
        Forward-backward error (px), inf where LK failed.
    """
    p0 = (prev_uv - prev_origin).astype(np.float32).reshape(-1, 1, 2)
    g0 = (guess_uv - cur_origin).astype(np.float32).reshape(-1, 1, 2)
    win = (2 * half + 1, 2 * half + 1)
    flags = cv2.OPTFLOW_USE_INITIAL_FLOW
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(
        prev_u8, cur_u8, p0, g0.copy(), winSize=win, maxLevel=levels,
        criteria=_PYR_CRITERIA, flags=flags,
    )  # fmt: skip
    p2, st2, _ = cv2.calcOpticalFlowPyrLK(
        cur_u8, prev_u8, p1, p0.copy(), winSize=win, maxLevel=levels,
        criteria=_PYR_CRITERIA, flags=flags,
    )  # fmt: skip
    ok = (st1.ravel() == 1) & (st2.ravel() == 1)
    uv = p1.reshape(-1, 2).astype(np.float64) + cur_origin
    fb = np.hypot(*(p2.reshape(-1, 2) - p0.reshape(-1, 2)).T).astype(np.float64)
    uv[~ok] = np.nan
    fb[~ok] = np.inf
    return uv, fb
