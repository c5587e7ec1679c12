"""The magnifier tip: the black end face, found by colour and located by its edge.

1. Segmentation. In a window around the expected tip, the brightness of the
   white-balanced pixel's brightest channel, V = max(B, G, R), is low only on
   the black face: about 0.1 of the cloth, against >= 0.4 on the shaded red rod
   and >= 0.8 on the red cross, the blue square and the cloth. A threshold
   between the window's dark and bright levels, and the connected component
   nearest the expected position, give a seed centre and radius.
2. Sub-pixel edge. Along rays from the seed, the face's edge is where the
   luma rises fastest (see :func:`brightness`), searched near V's threshold
   crossing. Unlike a threshold, the steepest point of a blurred step does
   not depend on how bright the other side is (red, blue or cloth), so the
   edge is unbiased wherever the face lies. Where luma's steepest rise is not
   where V's is (a stronger luma edge just beyond a dark colour), the ray is
   left out.
3. An ellipse fitted to the edge points gives the face's centroid, which the
   pose fit compares with the model's projected-rim centroid.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from camwhisker.kernels import tip as kernels
from camwhisker.sensor.polygon import polygon_centroid
from camwhisker.vision.blobs import blobs
from camwhisker.vision.blur import erf_sigmas

__all__ = [
    "TipMeasurement",
    "find_tip",
    "tip_edge_points",
    "ellipse_centre",
    "rim_centre",
    "blurred_rim",
    "rim_scale",
    "edge_blur_px",
    "brightness",
    "face_near",
]

#: Threshold between the window's dark (face, ~0.1 of the cloth) and bright levels:
#: 0.15 of the way keeps the face apart from the rod's darkest flank (~0.4) and the
#: grey springs (~0.65) under vignetting and 5 DN noise.
TIP_THRESHOLD_FRACTION = 0.15
#: A blob whose radius is over JOINED_RADIUS times the face's has the rod's flank
#: joined to it (a dark red rod's lies near 0.15); LOW_THRESHOLD_FRACTION, half the
#: way, parts them, with the face ~0.08 below it and 5 DN noise.
JOINED_RADIUS = 1.1
LOW_THRESHOLD_FRACTION = 0.075
#: The dark level is the percentile of V that falls this deep inside the expected
#: face area (a quarter of it), however large the window; the bright level is the
#: BRIGHT_PERCENTILE of the window (red, blue or cloth, never the face).
DARK_AREA_FRACTION = 0.25
BRIGHT_PERCENTILE = 90.0
#: Subsampling step for the level percentiles (speed; levels are smooth), at full
#: resolution and on the coarse grid alike.
LEVEL_STEP_PX = 3
#: Searches wider than this (px) start on a grid of every COARSE_STEP_PX-th pixel:
#: 64 times fewer pixels, and the face (~60-72 px across) is still 7-9 grid pixels.
COARSE_ABOVE_PX = 80.0
COARSE_STEP_PX = 8
#: A face cut by its search window's edge is looked for again in a window centred
#: on its visible part, this much wider than its radius (px), before a coarse search.
RECENTRE_MARGIN_PX = 4.0
#: Rays for the edge search; 48 keeps the ellipse centre's noise ~0.02 px.
N_RAYS = 48
#: The edge is searched within this many pixels of the threshold crossing (3 sigma
#: of the strongest blur we expect, 2.6 px) at this radial step.
EDGE_SEARCH_PX = 8.0
EDGE_STEP_PX = 0.5
#: Smoothing of the radial luma profiles before their derivative (px).
EDGE_SMOOTH_PX = 1.0
#: Component area accepted relative to the expected face area.
AREA_RANGE = (0.35, 2.5)
#: A ray's edge is kept when its rise is at least this fraction of the median rise.
#: Against the red cross or the rod's shaded flank luma rises 0.2-0.4 as steeply as
#: against the cloth, and where those rays go, the centre rests on the rest of the rim.
MIN_RISE_FRACTION = 0.15
#: A ray is left out where the steepest rises of luma and of V lie farther apart than
#: this (px): V rises at the face's own edge, while luma can jump to a stronger edge
#: just beyond a dark colour (blue to cloth, where the face crosses the blue square).
#: 1.5 px is the two's usual spread under the hard scene's blur.
EDGE_AGREE_PX = 1.5
#: Rays beside the rod's body are not used: where the body's outline reaches more
#: than BODY_PROTRUSION_PX beyond the face's rim, and BODY_BLUR_PX (along the rim)
#: around that: the body's shaded flank merges with the face's edge under the
#: blur (3 sigma of the hard scene's 2.6 px) and pulls the steepest point outward
#: by up to 3 px. Directions are tested at BODY_ANGLES points around the rim.
BODY_PROTRUSION_PX = 0.5
BODY_BLUR_PX = 8.0
BODY_ANGLES = 180
#: Fewest rays for the model-rim fit, and its iterations.
MIN_RIM_RAYS = 12
RIM_FIT_ITER = 10
#: The rim fit stops when its step is below this (px): far below the noise, so
#: the result does not depend on where it started.
RIM_FIT_TOL_PX = 1e-6
#: Ellipse refit drops edge points farther than this from the first fit (px).
OUTLIER_PX = 1.5
#: Half-width (px) of the luma profile across the face's edge that :func:`edge_blur_px`
#: fits: past ~1 blur sigma on each side, short of the next feature's edge.
BLUR_WINDOW_PX = 3.0
#: ... sampled this finely (px): a few samples per sigma at the sharpest builds' ~1 px.
BLUR_STEP_PX = 0.25
#: Soft-L1 scale (DN) of that fit: JPEG ringing and noise of a few DN count fully.
BLUR_FIT_DN = 2.0
#: An ellipse fitted to the edge is refused when its minor axis is under this
#: fraction of its major one: the model's rim projects to 0.50 or more at tilts
#: to 45 deg (every direction, dz -0.5 to 1 mm); collinear points give ~0.003.
ELLIPSE_MIN_AXIS_RATIO = 0.3
#: A pixel is dark enough to be the face when V is below this fraction of the
#: cloth's brightness: the face is at ~0.1 of the cloth, the rod's darkest flank
#: at ~0.4 (~0.28 where vignetting takes 30% off). Used only to tell that the face
#: is NOT near a position, so the margin is on the face's side.
FACE_DARK_FRACTION = 0.25


@dataclass(frozen=True)
class TipMeasurement:
    """centre_uv: ndarray, shape (2,), the end face's centroid (NaN if not found);
    radius_px: mean radius; ok: found whole and inside the image; reason: why not."""

    centre_uv: np.ndarray
    radius_px: float
    ok: bool
    reason: str = ""


def brightness(bgr: np.ndarray, gains: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(V, Y) of the white-balanced pixels, float32 each, shape (h, w).

    V = max(gB B, gG G, gR R) is the brightest channel, low only on the black
    face. Y is Rec. 601 luma: JPEG (and so MJPG) keeps luma at full resolution
    but halves the chroma; the brightest channel of a red or blue pixel is
    mostly chroma, and its edges come back from the codec ~0.7 px off and
    blocky. Edges are located in luma.
    """
    return kernels.brightness(np.asarray(bgr), np.asarray(gains, np.float32))


def face_near(frame, gains, centres_uv, radius_px: float, cloth_dn: float) -> bool:
    """Whether the face may lie near any of the positions: a quick look before a search.

    Samples a 3 x 3 grid, spacing half the face's radius, around each position
    (K, 2); True if any sample's V (see :func:`brightness`) is darker than
    FACE_DARK_FRACTION of ``cloth_dn``, the cloth's white-balanced brightness. A
    face that covers none of the samples lies over 1.5 radii from every position.
    """
    level = np.float32(FACE_DARK_FRACTION * cloth_dn)
    return kernels.any_dark(np.asarray(frame), np.asarray(gains, np.float32),
                            np.asarray(centres_uv, float).reshape(-1, 2), float(radius_px), level)


def _not_found(reason: str) -> TipMeasurement:
    return TipMeasurement(np.full(2, np.nan), math.nan, False, reason)


def find_tip(
    frame: np.ndarray,
    gains: np.ndarray,
    guess_uv: np.ndarray,
    radius_px: float,
    search_px: float,
    rim_uv: np.ndarray | None = None,
    body_hull_uv: np.ndarray | None = None,
) -> TipMeasurement:
    """Locate the tip's end face near an expected position.

    Parameters
    ----------
    frame : ndarray, shape (H, W, 3), uint8
        BGR frame; not modified.
    gains : ndarray, shape (3,)
        White-balance gains.
    guess_uv : ndarray, shape (2,)
        Expected centre of the face.
    radius_px : float
        Expected radius of the face.
    search_px : float
        How far the face may be from ``guess_uv``.
    rim_uv, body_hull_uv : ndarray, optional
        The model's rim and rod outline, see :func:`rim_centre`; without them
        an ellipse is fitted to the edge.

    Returns
    -------
    TipMeasurement
    """
    pts, _, reason = tip_edge_points(frame, gains, guess_uv, radius_px, search_px)
    if pts is None:
        return _not_found(reason)
    if rim_uv is None:
        return ellipse_centre(pts)
    return rim_centre(pts, rim_uv, body_hull_uv)


def tip_edge_points(frame, gains, guess_uv, radius_px, search_px):
    """Sub-pixel edge points of the end face, shape (N, 2), and the centroid (2,)
    of the dark blob they were searched around: (points, centroid, ""), or
    (None, None, reason) where the face is not found.

    See :func:`find_tip` for the parameters. A search wider than
    COARSE_ABOVE_PX first finds the face on a grid of every COARSE_STEP_PX-th
    pixel, then searches the full-resolution pixels around it. The blob's
    centroid lies within ~1 px of the face's: under the blur the threshold's
    crossing moves a little toward the darker neighbour.
    """
    if search_px > COARSE_ABOVE_PX:
        found = _coarse_blob(frame, gains, guess_uv, radius_px, search_px)
        if found is None:
            return None, None, "no dark blob of the tip's size where the tip can be"
        # The coarse centroid lies within a grid step of the face's (a face cut by
        # the window is looked for again below).
        guess_uv, search_px = found, COARSE_STEP_PX + 4.0
    h, w = frame.shape[:2]
    for attempt in range(2):
        half = radius_px * 1.4 + search_px
        u0 = max(int(guess_uv[0] - half), 0)
        v0 = max(int(guess_uv[1] - half), 0)
        u1 = min(int(guess_uv[0] + half) + 1, w)
        v1 = min(int(guess_uv[1] + half) + 1, h)
        if u1 - u0 < 8 or v1 - v0 < 8:
            return None, None, "tip window outside the frame"
        val, lum = brightness(frame[v0:v1, u0:u1], gains)
        found = _face_blob(val, guess_uv - (u0, v0), radius_px)
        if isinstance(found, str):
            return None, None, found
        seed, r_seed, thr, (x, y, bw, bh) = found
        touches = (x == 0 and u0 > 0) or (y == 0 and v0 > 0) or (
            x + bw == val.shape[1] and u1 < w) or (y + bh == val.shape[0] and v1 < h)  # fmt: skip
        if not touches:
            break
        if attempt == 1:
            return None, None, "dark blob reaches the tip window's edge"
        # Cut by the window's edge: the face's centre lies within a radius of the
        # visible part's; look again around it.
        guess_uv, search_px = seed + (u0, v0), radius_px + RECENTRE_MARGIN_PX
    if x == 0 or y == 0 or x + bw == val.shape[1] or y + bh == val.shape[0]:
        return None, None, "tip touches the image border"
    pts = _edge_points(val, lum, seed, r_seed, thr)
    if pts is None or len(pts) < N_RAYS // 2:
        return None, None, "tip edge not found on enough rays"
    return pts + (u0, v0), seed + (u0, v0), ""


def _face_blob(val, guess_xy, radius_px):
    """:func:`_dark_blob` at the face's threshold, or at the lower one where the
    rod's flank has joined the face's blob: (centroid, radius, threshold, bbox) or
    the reason it failed."""
    found = _dark_blob(val, guess_xy, radius_px, LEVEL_STEP_PX)
    if isinstance(found, str) or found[1] <= JOINED_RADIUS * radius_px:
        return found
    lower = _dark_blob(val, guess_xy, radius_px, LEVEL_STEP_PX, LOW_THRESHOLD_FRACTION)
    return found if isinstance(lower, str) else lower


def _dark_blob(val, guess_xy, radius_px, level_step, fraction=TIP_THRESHOLD_FRACTION):
    """The dark component of the face's size nearest ``guess_xy`` in ``val``, below
    ``fraction`` of the way from the window's dark level to its bright one.

    Returns (centroid, radius, threshold, bbox) or the reason it failed.
    """
    sub = val[::level_step, ::level_step] if level_step > 1 else val
    area_exp = math.pi * radius_px**2
    dark_pct = min(100.0 * DARK_AREA_FRACTION * area_exp / val.size, 50.0)
    flat = sub.ravel()
    k_dark = int(dark_pct / 100.0 * (flat.size - 1))
    k_bright = int(BRIGHT_PERCENTILE / 100.0 * (flat.size - 1))
    part = np.partition(flat, (k_dark, k_bright))
    dark, bright = float(part[k_dark]), float(part[k_bright])
    if bright - dark <= 0:
        return "no contrast in the tip window"
    thr = dark + fraction * (bright - dark)
    mask = cv2.threshold(val, thr, 1, cv2.THRESH_BINARY_INV)[1].astype(np.uint8)
    found = blobs(mask)
    if len(found) == 0:
        return "no dark blob near the expected tip"
    good = (found.area > AREA_RANGE[0] * area_exp) & (found.area < AREA_RANGE[1] * area_exp)
    if not good.any():
        return "no dark blob of the tip's size near the expected tip"
    dist = np.hypot(*(found.centroid - guess_xy).T)
    dist[~good] = np.inf
    k = int(np.argmin(dist))
    return found.centroid[k], math.sqrt(found.area[k] / math.pi), thr, found.box[k]


def _coarse_blob(frame, gains, guess_uv, radius_px, search_px):
    """Centre (u, v) of the face found on a coarse pixel grid, or None."""
    h, w = frame.shape[:2]
    s = COARSE_STEP_PX
    half = radius_px * 1.4 + search_px
    u0 = max(int(guess_uv[0] - half), 0)
    v0 = max(int(guess_uv[1] - half), 0)
    u1 = min(int(guess_uv[0] + half) + 1, w)
    v1 = min(int(guess_uv[1] + half) + 1, h)
    if u1 - u0 < 8 * s or v1 - v0 < 8 * s:
        return None
    val, _ = brightness(frame[v0:v1:s, u0:u1:s], gains)
    found = _dark_blob(val, (guess_uv - (u0, v0)) / s, radius_px / s, LEVEL_STEP_PX)
    if isinstance(found, str):
        return None
    return found[0] * s + (u0, v0)


def ellipse_centre(pts: np.ndarray) -> TipMeasurement:
    """Face centroid as the centre of an ellipse fitted to edge points (N, 2)."""
    centre, r_mean = _fit_ellipse_centre(pts)
    if centre is None:
        return _not_found("tip edge is not an ellipse")
    return TipMeasurement(centre, r_mean, True)


def rim_centre(pts: np.ndarray, rim_uv: np.ndarray, body_hull_uv: np.ndarray | None = None):
    """Face centroid from edge points (N, 2) and the model's rim polygon (M, 2).

    The model rim is shifted to fit the edge points; the result is the shifted
    rim's area centroid. This needs only part of the edge, so rays where the face
    borders the rod's own body (outline ``body_hull_uv``, shape (L, 2)) are left out.
    """
    pts = np.asarray(pts, float)
    rim = np.asarray(rim_uv, float)
    if body_hull_uv is not None:
        pts = pts[~_beside_body(pts, rim, body_hull_uv)]
    if len(pts) < MIN_RIM_RAYS:
        return _not_found("too little of the tip's edge is clear of the rod")
    centre, r_mean = _fit_rim_shift(pts, rim)
    if centre is None:
        return _not_found("tip edge does not fit the model's rim")
    return TipMeasurement(centre, r_mean, True)


def blurred_rim(rim_uv: np.ndarray, blur_px: float) -> np.ndarray:
    """Where the edge of a face with outline ``rim_uv`` (M, 2) is found under a blur of
    Gaussian sigma ``blur_px``: each point moved toward the centroid by blur^2 / (2 r),
    r the mean radius (see :func:`rim_scale`). Unmoved where the blur is NaN or 0.

    Where the rod's body hides part of the edge (at tilt), a rim fitted to the rest of
    it without this shift moves away from it by about that much."""
    rim = np.asarray(rim_uv, float)
    if not blur_px > 0:
        return rim
    c = polygon_centroid(rim)
    d = rim - c
    r2 = float((d[:, 0] ** 2 + d[:, 1] ** 2).sum()) / len(d)  # np.mean's sum, fewer calls
    return c + d * (1.0 - blur_px**2 / (2.0 * r2))


def rim_scale(pts: np.ndarray, rim_uv: np.ndarray, body_hull_uv: np.ndarray,
              blur_px: float = 0.0) -> float:  # fmt: skip
    """How much larger the face is than the model's rim: the relative scale s in the
    least-squares fit of the rim, shifted and scaled by 1 + s, to the edge points
    (N, 2) clear of the rod's body (see :func:`rim_centre`); NaN where too few.

    A blur of Gaussian sigma ``blur_px`` moves a curved edge's steepest rise inward
    by blur^2 / (2 r), r its radius of curvature, so the face's own scale is the
    fit's plus blur^2 / (2 r^2), r the fitted rim's mean radius.
    """
    pts = np.asarray(pts, float)
    rim = np.asarray(rim_uv, float)
    pts = pts[~_beside_body(pts, rim, body_hull_uv)]
    if len(pts) < MIN_RIM_RAYS:
        return math.nan
    c0 = polygon_centroid(rim)
    ar, rr = kernels.polar(rim, c0)
    t, s = np.zeros(2), 0.0
    use = np.ones(len(pts), bool)
    for _ in range(RIM_FIT_ITER):
        d = pts - c0 - t
        rho = np.hypot(d[:, 0], d[:, 1])
        r_model = np.interp(np.arctan2(d[:, 1], d[:, 0]), ar, rr) * (1.0 + s)
        a = np.column_stack([d / rho[:, None], r_model])
        res = rho - r_model
        step = np.linalg.lstsq(a[use], res[use], rcond=None)[0]
        use = np.abs(res - a @ step) <= OUTLIER_PX
        if use.sum() < MIN_RIM_RAYS:
            return math.nan
        t += step[:2]
        s = (1.0 + s) * (1.0 + step[2]) - 1.0
        if np.abs(step[:2]).max() < RIM_FIT_TOL_PX:
            break
    r = rr[1:-1].mean() * (1.0 + s)
    return float((1.0 + s) * (1.0 + blur_px**2 / (2.0 * r * r)) - 1.0)


def edge_blur_px(lum: np.ndarray, pts: np.ndarray, rim_uv: np.ndarray,
                 body_hull_uv: np.ndarray) -> float:  # fmt: skip
    """The blur across the face's edge: Gaussian sigma (px), the median over the edge
    points (N, 2) clear of the rod's body of an error function fitted to the luma
    ``lum`` (:func:`brightness`) along the ray from the rim's centroid through each
    point; NaN where no ray's fit rises within the window.
    """
    pts = np.asarray(pts, float)
    rim = np.asarray(rim_uv, float)
    pts = pts[~_beside_body(pts, rim, body_hull_uv)]
    if not len(pts):
        return math.nan
    c = polygon_centroid(rim)
    u = (pts - c) / np.hypot(*(pts - c).T)[:, None]
    x = np.arange(-BLUR_WINDOW_PX, BLUR_WINDOW_PX + 1e-9, BLUR_STEP_PX)
    mx, my = (pts[:, :, None] + u[:, :, None] * x).transpose(1, 0, 2).astype(np.float32)
    prof = cv2.remap(lum, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
    sigma = erf_sigmas(x, prof.astype(float), BLUR_FIT_DN)
    return float(np.nanmedian(sigma)) if np.isfinite(sigma).any() else math.nan


def _beside_body(pts: np.ndarray, rim: np.ndarray, body_hull_uv: np.ndarray) -> np.ndarray:
    """Edge points whose ray passes where the rod's body shows beside the face.

    In polar coordinates about the rim's centroid, the rod's outline reaches
    beyond the rim where the body shows (by more than BODY_PROTRUSION_PX); rays
    within BODY_BLUR_PX (as an arc on the rim) of such a direction are flagged,
    since the blur spreads the body's shaded flank that far.
    """
    hull = cv2.convexHull(np.asarray(body_hull_uv, np.float32)).reshape(-1, 2).astype(float)
    return kernels.beside_body_kernel(np.ascontiguousarray(pts, float),
                                      np.ascontiguousarray(rim, float), hull, BODY_ANGLES,
                                      BODY_PROTRUSION_PX, BODY_BLUR_PX)  # fmt: skip


def _fit_rim_shift(pts: np.ndarray, rim: np.ndarray):
    """Shift t that best puts the model rim on the edge points.

    Linearised radial residuals about the rim's centroid, iterated (dropping
    points off by more than OUTLIER_PX while MIN_RIM_RAYS remain); returns (rim
    centroid + t, mean radius) or (None, nan).
    """
    centre, radius = kernels.rim_shift_kernel(np.ascontiguousarray(pts, float),
                                              np.ascontiguousarray(rim, float), RIM_FIT_ITER,
                                              RIM_FIT_TOL_PX, OUTLIER_PX, MIN_RIM_RAYS)  # fmt: skip
    if not np.isfinite(centre).all():
        return None, math.nan
    return centre, radius


@functools.cache
def _ray_directions() -> np.ndarray:
    """Unit directions of the N_RAYS edge-search rays, shape (N_RAYS, 2)."""
    ang = np.linspace(0.0, 2 * np.pi, N_RAYS, endpoint=False)
    return np.column_stack([np.cos(ang), np.sin(ang)])


@functools.cache
def _dog_kernel() -> np.ndarray:
    """Derivative-of-Gaussian kernel along a ray, per pixel of radius, shape (1, k)."""
    sig = EDGE_SMOOTH_PX / EDGE_STEP_PX
    half = int(math.ceil(3 * sig))
    x = np.arange(-half, half + 1, dtype=float)
    k = -x * np.exp(-0.5 * (x / sig) ** 2)
    k /= -(k * x).sum() * EDGE_STEP_PX  # unit response to a unit ramp per pixel
    # filter2D correlates: flip so the output is the derivative, not its negative.
    return k[::-1].reshape(1, -1).astype(np.float32)


def _edge_points(val, lum, seed, r_seed, thr):
    """Edge points (N, 2) in window pixels: along rays from ``seed``, the steepest
    rise of ``lum`` near where ``val`` crosses ``thr``; None if too few."""
    dirs = _ray_directions()
    lo = max(r_seed - EDGE_SEARCH_PX - 2, 1.0)
    radii = np.arange(lo, r_seed + EDGE_SEARCH_PX + 2, EDGE_STEP_PX)
    mx = (seed[0] + dirs[:, :1] * radii).astype(np.float32)
    my = (seed[1] + dirs[:, 1:] * radii).astype(np.float32)
    prof = cv2.remap(val, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    lprof = cv2.remap(lum, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    # Derivative of Gaussian along each ray (sigma EDGE_SMOOTH_PX): unbiased for a
    # symmetric edge, and it keeps the 5 DN noise from making false peaks.
    rise = cv2.filter2D(lprof, -1, _dog_kernel(), borderType=cv2.BORDER_REPLICATE)
    vrise = cv2.filter2D(prof, -1, _dog_kernel(), borderType=cv2.BORDER_REPLICATE)
    win = int(round(EDGE_SEARCH_PX / 2 / EDGE_STEP_PX))
    r_edge, valid = kernels.ray_edges(prof, rise, vrise, thr, win, radii, EDGE_STEP_PX,
                                      MIN_RISE_FRACTION, EDGE_AGREE_PX)
    if valid.sum() < N_RAYS // 2:
        return None
    pts = seed + dirs * r_edge[:, None]
    return pts[valid]


def _fit_ellipse_centre(pts: np.ndarray):
    """Centre of a least-squares ellipse (OpenCV's direct fit), with one round of
    outlier rejection; (None, nan) for no ellipse or one too flat to be the face."""
    for _ in range(2):
        if len(pts) < 6:
            return None, math.nan
        # Centred first: OpenCV fits and returns float32 (steps of 6e-5 px at 1000 px).
        m = pts.mean(axis=0)
        (cx, cy), (da, db), ang = cv2.fitEllipseDirect((pts - m).astype(np.float32))
        if not (np.isfinite(cx) and min(da, db) > ELLIPSE_MIN_AXIS_RATIO * max(da, db)):
            return None, math.nan
        cx, cy = cx + m[0], cy + m[1]
        # Distance of each point from the ellipse, approximately (radial).
        t = math.radians(ang)
        c, s = math.cos(t), math.sin(t)
        d = pts - (cx, cy)
        xr, yr = d[:, 0] * c + d[:, 1] * s, -d[:, 0] * s + d[:, 1] * c
        rho = np.hypot(xr / (da / 2), yr / (db / 2))
        res = (rho - 1.0) * (da + db) / 4
        keep = np.abs(res) < OUTLIER_PX
        if keep.all():
            break
        pts = pts[keep]
    return np.array([cx, cy]), (da + db) / 4
