"""Find the tracking features in a frame without help: square, cross, tip.

The blue square and the red cross are the large components of the contrast
map of eq. (1) above +BLUE_MIN and below -RED_MIN; the tip is the dark blob
of :mod:`camwhisker.vision.tip`. Corners come from the convex outline of each
component, are assigned to the model's corners by their direction from the
component's centre, and are refined to sub-pixel with ``cv2.cornerSubPix``
on the one-signed contrast map of their own feature.

:func:`detect_features` raises :class:`FeaturesNotFound`, naming every
feature it could not find. Given the user's rough positions
(:class:`~camwhisker.vision.hints.FeatureHints`), it searches each hinted
feature around its hint instead of where the model puts it at rest.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from camwhisker.sensor.model import N_SQUARE, TIP, PlateModel
from camwhisker.sensor.polygon import polygon_area
from camwhisker.vision.blobs import blobs
from camwhisker.vision.colour import contrast_map
from camwhisker.vision.hints import FeatureHints
from camwhisker.vision.tip import ellipse_centre, rim_centre, tip_edge_points

__all__ = [
    "FeaturesNotFound",
    "Detection",
    "detect_features",
    "refine_corners",
    "BLUE_MIN",
    "RED_MIN",
    "WAY_OUT",
]

#: Contrast-map levels that separate the features from the cloth (G ~ 0): the
#: square is at ~ +1.4 and the cross at ~ -1.6; half-way is robust to a 30% cast.
BLUE_MIN = 0.6
RED_MIN = 0.6
#: A component is accepted when its area is within this factor range of the model's.
AREA_RANGE = (0.4, 1.8)
#: Detected corners farther than this from the model's direction (deg) are rejected.
ANGLE_TOL_DEG = 12.0
#: Corner refinement: edge points are sampled along each of a corner's two edges
#: from EDGE_FROM_PX to EDGE_TO_PX away from it (clear of the rounded blur at the
#: corner itself), each found as the steepest point of a profile across the edge
#: within +-EDGE_HALF_PX (3 sigma of a 2.6 px blur); the corner is where the two
#: fitted lines meet. A blurred corner's saddle point (cornerSubPix) sits ~1.5 px
#: inside the true corner; the lines' intersection does not.
EDGE_FROM_PX = 6.0
EDGE_TO_PX = 22.0
EDGE_HALF_PX = 8.0
EDGE_STEP_PX = 0.25
#: A refined corner farther than this from its polygon vertex is rejected (px): the
#: polygon cuts a corner blurred by sigma = 2.6 px by up to ~6 px.
REFINE_MAX_SHIFT_PX = 8.0
#: A corner still lost is refined once more from its edges' profiles smoothed by this
#: Gaussian (px): under heavy blur and noise the steepest point of a wide ramp, taken
#: from differences EDGE_STEP_PX apart, scatters over pixels and tilts the edge's line.
LOST_SMOOTH_PX = 1.0
#: Fallback for a feature cut into pieces: components whose centre lies within this
#: factor of the model outline's radius, and larger than this share of its area, join.
MERGE_REACH = 1.2
MERGE_MIN_AREA = 0.02
#: A pieced-together feature must keep the model's shape: its corners' mutual
#: distances within this share (a build's scale: focal length, depth, sizes) plus
#: MERGE_SHAPE_PX (a corner's error) of the model's.
MERGE_SHAPE_TOL = 0.12
MERGE_SHAPE_PX = 6.0
#: A light cross centre is at most this many arm widths across (closing bridges it).
CENTRE_GAP_ARMS = 1.8
#: Refinement passes (the second starts from the first's corner, so the edge
#: samples sit where the edges really are).
REFINE_PASSES = 2
#: The way out that every detection failure ends with.
WAY_OUT = "pass rough positions with --features FILE (see docs/sensor.md section 5.2)"


class FeaturesNotFound(ValueError):
    """Detection failed; ``missing`` names the features that were not found."""

    def __init__(self, missing: list[str], detail: str = ""):
        self.missing = list(missing)
        msg = "features not found: " + ", ".join(self.missing)
        super().__init__(msg + (f" ({detail})" if detail else "") + "; " + WAY_OUT)


@dataclass(frozen=True)
class Detection:
    """uv: ndarray, shape (13, 2), pixels of the points of POINT_NAMES (NaN where
    not found); found: ndarray of bool, shape (13,)."""

    uv: np.ndarray
    found: np.ndarray


def _component(mask: np.ndarray, area_exp: float, near_uv: np.ndarray | None):
    found = blobs(mask)
    if len(found) == 0:
        return None
    areas = found.area
    good = (areas > AREA_RANGE[0] * area_exp) & (areas < AREA_RANGE[1] * area_exp)
    if not good.any():
        return None
    score = np.abs(np.log(areas / area_exp))
    if near_uv is not None:
        score = score + np.hypot(*(found.centroid - near_uv).T) / math.sqrt(area_exp)
    score[~good] = np.inf
    k = int(np.argmin(score))
    return (found.labels == k + 1).astype(np.uint8), found.centroid[k]


def _assign_corners(hull: np.ndarray, centre: np.ndarray, model_dirs_deg: np.ndarray):
    """For each model direction, the hull vertex nearest in direction and farthest out."""
    d = hull - centre
    ang = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    rad = np.hypot(d[:, 0], d[:, 1])
    out = np.full((len(model_dirs_deg), 2), np.nan)
    for i, a in enumerate(model_dirs_deg):
        diff = np.abs((ang - a + 180.0) % 360.0 - 180.0)
        cand = diff < ANGLE_TOL_DEG
        if cand.any():
            j = np.flatnonzero(cand)[np.argmax(rad[cand] - 0.5 * diff[cand])]
            out[i] = hull[j]
    return out


def _polygon_corners(mask: np.ndarray, n_expected: int):
    """The largest component's outline simplified to a polygon: (its vertices (M, 2),
    the outline's points (P, 2), the simplification's tolerance in px), or None."""
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return None
    c = max(contours, key=cv2.contourArea)
    poly = c if n_expected != 4 else cv2.convexHull(c)
    tol_px = 0.01 * cv2.arcLength(poly, True)
    approx = cv2.approxPolyDP(poly, tol_px, True).reshape(-1, 2).astype(float)
    return approx, c.reshape(-1, 2).astype(float), tol_px


def _outermost(outline: np.ndarray, corners: np.ndarray, edge_dirs: np.ndarray,
               reach_px: float) -> np.ndarray:  # fmt: skip
    """Each corner (K, 2) moved to the outline's point within ``reach_px`` farthest out
    along the corner's bisector (away from both its edges): the corner itself."""
    out = corners.copy()
    for k, c in enumerate(corners):
        e = edge_dirs[k] / np.hypot(*edge_dirs[k].T)[:, None]
        near = outline[np.hypot(*(outline - c).T) <= reach_px]
        if len(near):
            out[k] = near[np.argmax(near @ -(e[0] + e[1]))]
    return out


def _edge_line(gmap: np.ndarray, corner: np.ndarray, along: np.ndarray, smooth_px: float = 0.0):
    """Point and unit direction of the edge leaving ``corner`` along ``along``; its
    profiles smoothed across the edge by a Gaussian of ``smooth_px`` (px) first."""
    e = along / np.hypot(*along)
    n = np.array([-e[1], e[0]])
    t = np.arange(EDGE_FROM_PX, EDGE_TO_PX + 1e-9, 1.0)
    s = np.arange(-EDGE_HALF_PX, EDGE_HALF_PX + 1e-9, EDGE_STEP_PX)
    base = corner + t[:, None] * e
    mx = (base[:, :1] + s[None, :] * n[0]).astype(np.float32)
    my = (base[:, 1:] + s[None, :] * n[1]).astype(np.float32)
    prof = cv2.remap(gmap, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    if smooth_px > 0:
        sig = smooth_px / EDGE_STEP_PX
        prof = cv2.GaussianBlur(prof, (2 * math.ceil(3 * sig) + 1, 1), sig,
                                borderType=cv2.BORDER_REPLICATE)  # fmt: skip
    grad = np.abs(np.gradient(prof, axis=1))
    j = np.clip(grad.argmax(axis=1), 1, len(s) - 2)
    rows = np.arange(len(t))
    ym, y0, yp = grad[rows, j - 1], grad[rows, j], grad[rows, j + 1]
    den = ym - 2 * y0 + yp
    frac = np.where(den < 0, 0.5 * (ym - yp) / np.where(den < 0, den, -1.0), 0.0)
    off = s[j] + np.clip(frac, -0.5, 0.5) * EDGE_STEP_PX
    pts = base + off[:, None] * n
    m = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - m)
    return m, vt[0]


def refine_corners(gmap: np.ndarray, corners: np.ndarray, edge_dirs: np.ndarray,
                   smooth_px: float = 0.0) -> np.ndarray:  # fmt: skip
    """Sub-pixel corners as intersections of their two edges.

    Parameters
    ----------
    gmap : ndarray, shape (H, W), float32
        One-signed contrast map of the feature (the feature bright, all else 0).
    corners : ndarray, shape (K, 2)
        Approximate corners (NaN rows are passed through).
    edge_dirs : ndarray, shape (K, 2, 2)
        Image directions of each corner's two edges, pointing away from it.
    smooth_px : float
        Gaussian smoothing of the edges' profiles (px; see :func:`_edge_line`).

    Returns
    -------
    ndarray, shape (K, 2)
        Refined corners; NaN where the refinement moved a corner by more
        than REFINE_MAX_SHIFT_PX or the edges are parallel.
    """
    out = np.full(corners.shape, np.nan)
    for k, c in enumerate(corners):
        if not np.isfinite(c).all():
            continue
        x = c
        for _ in range(REFINE_PASSES):
            p1, d1 = _edge_line(gmap, x, edge_dirs[k, 0], smooth_px)
            p2, d2 = _edge_line(gmap, x, edge_dirs[k, 1], smooth_px)
            a = np.column_stack([d1, -d2])
            if abs(np.linalg.det(a)) < 0.2:
                x = None
                break
            s1, _ = np.linalg.solve(a, p2 - p1)
            x = p1 + s1 * d1
        if x is not None and np.hypot(*(x - c)) <= REFINE_MAX_SHIFT_PX:
            out[k] = x
    return out


def detect_features(
    frame: np.ndarray,
    gains: np.ndarray,
    model: PlateModel,
    q: np.ndarray | None = None,
    require: tuple[str, ...] = ("square corners", "cross arm ends", "magnifier tip"),
    hints: FeatureHints | None = None,
) -> Detection:
    """Detect the square's corners, the cross's arm-end corners and the tip.

    Parameters
    ----------
    frame : ndarray, shape (H, W, 3), uint8
        BGR frame; not modified.
    gains : ndarray, shape (3,)
        White-balance gains.
    model : PlateModel
        Gives the expected sizes and corner directions.
    q : ndarray, shape (5,), optional
        Approximate pose for the expected sizes; rest pose if omitted.
    require : tuple of str
        Features whose absence raises. A required feature found in pieces (cut
        by a spring or the other feature, or a cross split by a light centre)
        is pieced together.
    hints : FeatureHints, optional
        The user's rough rest positions: a hinted feature's expected outline is
        moved so that its centre sits at the hint (the tip's search centre is
        the hint); the others are searched where the model puts them.

    Returns
    -------
    Detection

    Raises
    ------
    FeaturesNotFound
        Naming each required feature that was not found.
    """
    q = np.zeros(5) if q is None else np.asarray(q, float)
    uv_model, _, rim = model.project(q, jacobian=False)
    _, rod_rims_uv, cross_uv = model.outlines(q)
    corner_dirs = model.edge_directions(q)
    g = contrast_map(frame, gains)
    found_uv = np.full((TIP + 1, 2), np.nan)
    missing = []

    details = []
    hints = hints or FeatureHints()
    sq_model = _centred(uv_model[:N_SQUARE], hints.square_centre_px)
    blue = (g > BLUE_MIN).astype(np.uint8)
    found_uv[:N_SQUARE] = _feature_corners(
        blue, np.maximum(g, 0.0), sq_model, polygon_area(sq_model), 4, corner_dirs[:N_SQUARE],
        merge="square corners" in require,
    )  # fmt: skip
    if not np.isfinite(found_uv[:N_SQUARE]).all():
        missing.append("square corners")
        details.append(_found_where("square", "blue", blue, sq_model, found_uv[:N_SQUARE]))

    cr_model = _centred(uv_model[N_SQUARE:TIP], hints.cross_centre_px)
    red = (g < -RED_MIN).astype(np.uint8)
    found_uv[N_SQUARE:TIP] = _feature_corners(
        red, np.maximum(-g, 0.0), cr_model, polygon_area(cross_uv) * 0.85, 12,
        corner_dirs[N_SQUARE:TIP], "cross arm ends" in require, _centre_gap_px(model),
    )  # fmt: skip
    if not np.isfinite(found_uv[N_SQUARE:TIP]).all():
        missing.append("cross arm ends")
        details.append(_found_where("cross", "red", red, cr_model, found_uv[N_SQUARE:TIP]))

    tip_near = uv_model[TIP] if hints.tip_px is None else np.asarray(hints.tip_px)
    found_uv[TIP] = _tip(frame, gains, uv_model[TIP], rim, rod_rims_uv, tip_near)
    if not np.isfinite(found_uv[TIP]).all():
        missing.append("magnifier tip")
        details.append(f"tip: no dark end face near ({tip_near[0]:.0f}, {tip_near[1]:.0f}) px")

    need = [m for m in missing if m in require]
    if need:
        detail = "; ".join(d for d, m in zip(details, missing, strict=True) if m in need)
        raise FeaturesNotFound(need, detail)
    return Detection(found_uv, np.isfinite(found_uv).all(axis=1))


def _centred(model_uv: np.ndarray, centre_uv) -> np.ndarray:
    """The model's points (K, 2) moved so that their mean sits at ``centre_uv`` (a
    user's hint), or as they are where it is None."""
    if centre_uv is None:
        return model_uv
    return model_uv + (np.asarray(centre_uv, float) - model_uv.mean(axis=0))


def _tip(frame, gains, model_tip_uv, rim, rod_rims_uv, near_uv) -> np.ndarray:
    """The tip's centre (2,) searched around ``near_uv``, NaN where not found."""
    radius = math.sqrt(polygon_area(rim) / math.pi)
    h, w = frame.shape[:2]
    edges, _, _ = tip_edge_points(frame, gains, near_uv, radius, search_px=0.25 * max(h, w))
    tip = None if edges is None else ellipse_centre(edges)
    if tip is not None and tip.ok:
        # The model's rim, placed at the rough centre, refines it (see tip.rim_centre).
        shift = tip.centre_uv - model_tip_uv
        tip = rim_centre(edges, rim + shift, rod_rims_uv + shift)
    return tip.centre_uv if tip is not None and tip.ok else np.full(2, np.nan)


def _feature_corners(mask, gmap, model_uv, area_exp, n_vertices, edge_dirs, merge=True,
                     bridge_px=0.0):  # fmt: skip
    """A feature's corners (K, 2), NaN where not found: from its one component of
    ``mask``, else, with ``merge`` (a real build: a spring or the other feature
    cuts it, a light centre splits the cross), from the union of the components
    near the model's, their gaps bridged by ``bridge_px``. Only a required
    feature merges, so that a frame searched without requirements is unchanged."""
    centre_exp = model_uv.mean(axis=0)
    corners = _corners_of(_component(mask, area_exp, centre_exp), model_uv, n_vertices,
                          gmap, edge_dirs)  # fmt: skip
    if np.isfinite(corners).all() or not merge:
        return corners
    merged = _merged_component(mask, model_uv, area_exp, bridge_px)
    if merged is None:
        return corners
    again = _corners_of(merged, model_uv, n_vertices, gmap, edge_dirs)
    if not _same_shape(again, model_uv):  # pieces of something else, or a cut-off part
        return corners
    return again if np.isfinite(again).sum() > np.isfinite(corners).sum() else corners


def _same_shape(corners: np.ndarray, model_uv: np.ndarray) -> bool:
    """Whether the found corners' mutual distances match the model's, within a
    build's scale deviation (MERGE_SHAPE_TOL) plus a corner's error."""
    ok = np.isfinite(corners).all(axis=1)
    c, m = corners[ok], model_uv[ok]
    d = np.hypot(*(c[:, None] - c[None]).transpose(2, 0, 1))
    dm = np.hypot(*(m[:, None] - m[None]).transpose(2, 0, 1))
    return bool(np.all(np.abs(d - dm) <= MERGE_SHAPE_TOL * dm + MERGE_SHAPE_PX))


def _corners_of(comp, model_uv, n_vertices, gmap, edge_dirs) -> np.ndarray:
    out = np.full(model_uv.shape, np.nan)
    if comp is None:
        return out
    mask, centre = comp
    found = _polygon_corners(mask, n_vertices)
    if found is None:
        return out
    poly, outline, tol_px = found
    corners = _assign_corners(poly, centre, _dirs(model_uv, model_uv.mean(axis=0)))
    out = refine_corners(gmap, corners, edge_dirs)
    # A vertex can sit up to the tolerance off its corner where noise frays an edge.
    lost = np.isfinite(corners).all(axis=1) & ~np.isfinite(out).all(axis=1)
    if lost.any():
        out[lost] = refine_corners(gmap, _outermost(outline, corners[lost], edge_dirs[lost],
                                                    tol_px), edge_dirs[lost])  # fmt: skip
    lost = np.isfinite(corners).all(axis=1) & ~np.isfinite(out).all(axis=1)
    if lost.any():
        out[lost] = refine_corners(gmap, corners[lost], edge_dirs[lost], LOST_SMOOTH_PX)
    return out


def _merged_component(mask, model_uv, area_exp, bridge_px):
    """The union of the components whose centre lies within the model outline's
    reach (MERGE_REACH times its radius), as (mask, centre), if its area is right:
    filled to their convex hull for a convex feature (``bridge_px`` 0), else with
    gaps up to ``bridge_px`` closed."""
    found = blobs(mask)
    if len(found) == 0:
        return None
    centre = model_uv.mean(axis=0)
    reach = MERGE_REACH * np.hypot(*(model_uv - centre).T).max()
    near = (np.hypot(*(found.centroid - centre).T) < reach) & (
        found.area > MERGE_MIN_AREA * area_exp
    )
    if not near.any():
        return None
    union = np.isin(found.labels, np.flatnonzero(near) + 1).astype(np.uint8)
    if bridge_px == 0.0:  # a convex feature (the square): its pieces' hull
        v, u = np.nonzero(union)
        hull = cv2.convexHull(np.column_stack([u, v]).astype(np.int32))
        cv2.fillConvexPoly(union, hull, 1)
    else:
        k = 2 * int(math.ceil(bridge_px / 2)) + 1
        union = cv2.morphologyEx(union, cv2.MORPH_CLOSE,
                                 cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))  # fmt: skip
    area = float(union.sum())
    if not (AREA_RANGE[0] * area_exp < area < AREA_RANGE[1] * area_exp):
        return None
    v, u = np.nonzero(union)
    return union, np.array([u.mean(), v.mean()])


def _centre_gap_px(model: PlateModel) -> float:
    """Width in pixels of the largest light centre that can split the cross into its arms."""
    plate = model.sensor.plate
    return (
        CENTRE_GAP_ARMS
        * plate.cross_arm_mm
        * model.camera.fx_px
        / (plate.z_i_mm - plate.cross_offset_mm)
    )


def _found_where(feature: str, colour: str, mask, model_uv, corners) -> str:
    """What was found of a feature, and where, for the error message."""
    found = blobs(mask)
    centre = model_uv.mean(axis=0)
    order = np.argsort(-found.area)[:3]
    parts = ", ".join(f"{found.area[k]:.0f} px at ({found.centroid[k][0]:.0f}, "
                      f"{found.centroid[k][1]:.0f})" for k in order)  # fmt: skip
    ok = int(np.isfinite(corners).all(axis=1).sum())
    return (f"{feature}: {ok} of {len(corners)} corners; expected near ({centre[0]:.0f}, "
            f"{centre[1]:.0f}) px; largest {colour} regions: {parts or 'none'}")  # fmt: skip


def _dirs(uv: np.ndarray, centre: np.ndarray) -> np.ndarray:
    d = uv - centre
    return np.degrees(np.arctan2(d[:, 1], d[:, 0]))
