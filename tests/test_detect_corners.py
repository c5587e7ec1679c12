"""Corners of a feature from its thresholded outline, where noise frays an edge.

The outline is simplified to a polygon (tolerance 1 % of its perimeter, ~9 px for the
cross) and each vertex refined from the contrast map's two edges. Under a heavy blur the
thresholded corners are rounded; a bump of noise on an edge near a corner is then the
outline's farthest point from the simplification's chord, and the vertex lands on it, up
to the tolerance from the corner: farther than the refinement may move it. Such a vertex
is moved to the outline's point farthest out along the corner's bisector and refined
again. A corner still lost (heavy blur and noise scatter the edges' steepest points and
tilt their lines) is refined once more from profiles smoothed by LOST_SMOOTH_PX.

| check | expectation | reason |
|---|---|---|
| vertex with the bump | > REFINE_MAX_SHIFT_PX off | the case exists |
| every corner, bump or not | within 0.75 px of the corner | the refinement's own error, 0.55 px |
| blur 3 px, noise 0.05 of the contrast, 8 seeds | 64 of 64 corners (63 unsmoothed) | the retry |
| ... the corner the retry finds | within 2 px | the others: 0.3-6.2 px off, median 1.8 |
"""

import cv2
import numpy as np
import pytest

from camwhisker.vision import detect
from camwhisker.vision.detect import (
    RED_MIN,
    REFINE_MAX_SHIFT_PX,
    _assign_corners,
    _corners_of,
    _dirs,
    _polygon_corners,
)

CENTRE = np.array([648.0, 364.0])
REACH, HALF = 111.0, 34.0  # the arms' reach from the centre and half width, px
BLUR_PX = 2.6  # the hard look's Gaussian blur
TOL_PX = 0.75  # the refinement's own error on the clean cross: up to 0.55 px (blur 0.8-2.6)


def cross():
    """The cross's arm-end corners (8, 2), in the order of the sensor model's."""
    a, w = REACH, HALF
    return CENTRE + np.array([[a, -w], [a, w], [w, a], [-w, a], [-a, w], [-a, -w], [-w, -a],
                              [w, -a]])  # fmt: skip


def _bar(half_u: float, half_v: float) -> np.ndarray:
    """Exact area coverage of each pixel (centres on integers) by a centred rectangle."""
    def cover(n, lo, hi):
        i = np.arange(n)
        return np.clip(np.minimum(i + 0.5, hi) - np.maximum(i - 0.5, lo), 0.0, 1.0)

    return (cover(720, CENTRE[1] - half_v, CENTRE[1] + half_v)[:, None]
            * cover(1280, CENTRE[0] - half_u, CENTRE[0] + half_u)[None, :])  # fmt: skip


def edge_dirs(corners: np.ndarray) -> np.ndarray:
    """Each arm-end corner's two edges (8, 2, 2): across the end to its other corner, and
    along the arm toward the centre."""
    across = corners.reshape(4, 2, 2)[:, ::-1].reshape(8, 2) - corners
    offset = corners - CENTRE
    along = np.where(np.abs(offset) > HALF + 1, -np.sign(offset), 0.0)
    return np.stack([across / np.hypot(*across.T)[:, None], along], axis=1)


@pytest.fixture(scope="module")
def scene():
    area = _bar(REACH, HALF) + _bar(HALF, REACH) - _bar(HALF, HALF)  # the two bars' union
    gmap = cv2.GaussianBlur(area.astype(np.float32), (0, 0), BLUR_PX)
    corners = cross()
    return gmap, (gmap > RED_MIN).astype(np.uint8), corners  # as detection thresholds


@pytest.mark.parametrize("bump", [None, (9, 15), (8, 14)])
def test_a_bump_beside_a_rounded_corner_still_gives_every_corner(scene, bump):
    gmap, mask, corners = scene
    mask = mask.copy()
    if bump is not None:  # 2 px out on the left arm's left edge, just above its lower corner
        v_corner = int(CENTRE[1] + HALF)
        left = np.flatnonzero(mask[v_corner - 20])[0]
        mask[v_corner - bump[1]:v_corner - bump[0], left - 2:left] = 1
        poly = _polygon_corners(mask, 12)[0]
        vertex = _assign_corners(poly, CENTRE, _dirs(corners, CENTRE))[4]
        assert np.hypot(*(vertex - corners[4])) > REFINE_MAX_SHIFT_PX
    found = _corners_of((mask, CENTRE), corners, 12, gmap, edge_dirs(corners))
    assert np.hypot(*(found - corners).T).max() <= TOL_PX


def test_a_corner_lost_to_noise_is_refined_from_smoothed_profiles(monkeypatch):
    area = _bar(REACH, HALF) + _bar(HALF, REACH) - _bar(HALF, HALF)
    clean = cv2.GaussianBlur(area.astype(np.float32), (0, 0), 3.0)
    mask = (clean > RED_MIN).astype(np.uint8)
    corners = cross()
    found = {}
    for smooth in (0.0, detect.LOST_SMOOTH_PX):
        monkeypatch.setattr(detect, "LOST_SMOOTH_PX", smooth)
        found[smooth] = np.stack([
            _corners_of((mask, CENTRE), corners, 12, clean + np.random.default_rng(seed).normal(
                0.0, 0.05, clean.shape).astype(np.float32), edge_dirs(corners))
            for seed in range(8)])  # fmt: skip
    plain, retried = found[0.0], found[detect.LOST_SMOOTH_PX]
    ok = np.isfinite(plain).all(axis=-1)
    assert ok.sum() == 63 and np.isfinite(retried).all()
    assert np.array_equal(plain[ok], retried[ok])  # corners found before are unchanged
    truth = np.broadcast_to(corners, retried.shape)
    assert np.hypot(*(retried[~ok] - truth[~ok]).T).max() <= 2.0
