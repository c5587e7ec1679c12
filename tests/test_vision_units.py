"""Unit tests of the front end's parts, on hand-worked values and synthetic images.

Tolerances (and why):

| quantity | tol | reason |
|---|---|---|
| paper equations | 1e-9 relative | closed-form arithmetic |
| eq. (1) | 1e-6 | float32 arithmetic |
| pose round trip | 1e-9 mm / rad | Gauss-Newton to GN_STEP_TOL on exact data |
| pose refit, tip moves <= 2 px | 1e-5 rad, 2e-4 mm | one Gauss-Newton step leaves ~step^2 |
| LK, noise-free shift | 0.02 px | bilinear interpolation of a blurred edge |
| LK, zero motion | 1e-6 px | template == image: the first step is exactly 0 |
| tip centre, noise-free | 0.05 px | 48 edge points on an antialiased disc |
| tip centre, rim 0.5 px small | 0.1 px | whole edge: the shift absorbs none of it (0.016 px) |
| rim scale, exact edge points | 1e-4 | a 720-gon's chords |
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from camwhisker.sensor.file import Sensor
from camwhisker.sensor.model import TIP, PlateModel
from camwhisker.sensor.plate import Pose, feature_pixels
from camwhisker.sensor.polygon import polygon_area, polygon_centroid
from camwhisker.vision import paper
from camwhisker.vision.blobs import blobs
from camwhisker.vision.colour import (
    CLOTH_MIN_SAMPLES,
    cloth_samples,
    contrast_map,
    share_patches,
    unmixed_maps,
    unmixing_weights,
    white_balance_gains,
)
from camwhisker.vision.lk import refine_first_template, warp_templates
from camwhisker.vision.pose import fit_pose, refit_pose
from camwhisker.vision.tip import (
    BODY_ANGLES,
    BODY_BLUR_PX,
    BODY_PROTRUSION_PX,
    JOINED_RADIUS,
    LEVEL_STEP_PX,
    N_RAYS,
    _beside_body,
    _dark_blob,
    brightness,
    edge_blur_px,
    ellipse_centre,
    face_near,
    find_tip,
    rim_centre,
    rim_scale,
    tip_edge_points,
)

# ------------------------------------------------------------------ paper eqs


def test_eq2_axial_deflection_hand_value():
    # 25 * (1 - 200 / 210) = 25 * 10 / 210
    assert paper.axial_deflection(25.0, 200.0, 210.0) == pytest.approx(250.0 / 210.0, rel=1e-12)
    assert paper.axial_deflection(25.0, 200.0, 200.0) == 0.0


def test_eqs3_4_tip_shift_hand_value():
    # (25 - 7.5) * 10 / (17.5 - 0.5) - 10 = 175 / 17 - 10
    got = paper.tip_shift_from_dz(25.0, 7.5, np.array([10.0, -4.0]), 0.5)
    np.testing.assert_allclose(got, [175.0 / 17.0 - 10.0, -70.0 / 17.0 + 4.0], rtol=1e-12)


def test_eq5_eq6_table_one_values():
    u_aov, v_aov = math.radians(26.95), math.radians(16.26)
    # tan(26.95 deg) = 0.5084267153, tan(16.26 deg) = 0.2916627899
    # mu = (720 / 1280) * 0.5084267153 / 0.2916627899 = 0.98055027
    mu = paper.v_u_corrector(25.0, 7.5, 1280, 720, u_aov, v_aov)
    assert mu == pytest.approx(0.98055027, rel=1e-7)
    # rho = 0.5 * 17.5 * (0.5084267153 / 1280 + 0.2916627899 / 720) = 0.0070200863
    rho = paper.mm_per_px(25.0, 7.5, 1280, 720, u_aov, v_aov)
    assert rho == pytest.approx(0.0070200863, rel=1e-7)


def test_eq7_rotation_magnitude_hand_value():
    # atan(0.007 * sqrt(30^2 + 40^2) / 7.5) = atan(0.0466667) = 2.6718646 deg
    phi = paper.rotation_magnitude(0.007, 30.0, 40.0, 1.0, 7.5)
    assert math.degrees(phi) == pytest.approx(2.6718646, rel=1e-7)
    # mu scales the v component: sqrt(30^2 + 39.2^2) = 49.3628...
    phi = paper.rotation_magnitude(0.007, 30.0, 40.0, 0.98, 7.5)
    assert math.degrees(phi) == pytest.approx(2.6378379, rel=1e-7)


def test_paper_geometry_defaults_reproduce_table_one():
    g = paper.PaperGeometry.from_sensor(Sensor())
    # The default intrinsics are rounded to 0.01 px: mu and rho agree to ~1e-5.
    assert g.mu == pytest.approx(0.98055, abs=2e-5)
    assert g.rho_mm_per_px == pytest.approx(0.00702009, rel=1e-5)
    dz, phi, theta = g.solve(200.0, np.array([200.0]), np.array([639.5, 359.5]),
                             np.array([[669.5, 319.5]]))  # fmt: skip
    assert dz[0] == 0.0
    expected = math.atan(g.rho_mm_per_px * math.hypot(30.0, 40.0 * g.mu) / 7.5)
    assert phi[0] == pytest.approx(expected, rel=1e-12)
    assert math.degrees(theta[0]) == pytest.approx(math.degrees(math.atan2(-40, 30)), abs=1e-9)


def _paper_points(scale: float) -> np.ndarray:
    """13 points (square TL, TR, BR, BL; arm ends +u, +v, -u, -v in pairs; tip) about
    (100, 80), spread by ``scale``: cross widths 100 and 80 px, square 10 and 8 px."""
    square = [(-5, -4), (5, -4), (5, 4), (-5, 4)]
    arms = [(60, -1), (60, 1), (-1, 50), (1, 50), (-40, 1), (-40, -1), (1, -30), (-1, -30)]
    uv = np.array(square + arms + [(0, 0)], float) * scale + (100.0, 80.0)
    uv[-1] = (130.0, 60.0)  # the tip does not scale
    return uv


def test_projected_widths_by_hand():
    np.testing.assert_allclose(paper.projected_widths(_paper_points(1.0)), [100, 80, 10, 8])
    hidden = _paper_points(1.0)
    hidden[4] = np.nan  # one end of the +u arm
    assert np.isnan(paper.projected_widths(hidden)[0])


def test_paper_pose_substitutes_a_width_where_an_arm_end_is_hidden():
    g = paper.PaperGeometry.from_sensor(Sensor())
    rest = paper.PaperRest.from_points(_paper_points(1.0))
    moved = _paper_points(1.03)
    dz, _, _ = g.pose_from_points(rest, moved)
    assert dz == pytest.approx(g.z_i_mm * (1 - 100 / 103), rel=1e-12)  # Eq. (2) on b_u
    moved[5] = np.nan
    dz_v, phi, theta = g.pose_from_points(rest, moved)
    assert dz_v == pytest.approx(g.z_i_mm * (1 - 80 / 82.4), rel=1e-12)  # b_v substituted
    assert np.isfinite([phi, theta]).all()
    moved[-1] = np.nan
    assert np.isnan(g.pose_from_points(rest, moved)).all()


# ------------------------------------------------------------------ colour


def test_eq1_contrast_values_and_black_pixel():
    px = np.array([[[185, 80, 40], [45, 50, 200], [0, 0, 0], [100, 100, 100]]], np.uint8)
    g = contrast_map(px)
    p_blue, p_red = (185 + 80 + 40) / 3, (45 + 50 + 200) / 3
    np.testing.assert_allclose(g[0], [(185 - 40) / p_blue, (45 - 200) / p_red, 0.0, 0.0], atol=1e-6)
    assert np.isfinite(g).all()


def test_eq1_does_not_touch_input_and_gains_apply():
    px = np.array([[[100, 120, 140]]], np.uint8)
    before = px.copy()
    g = contrast_map(px, np.array([1.4, 1.0, 1.0]))
    # B' = 140, R = 140 -> G = 0
    assert abs(g[0, 0]) < 1e-6
    np.testing.assert_array_equal(px, before)


def test_white_balance_undoes_a_cast():
    rng = np.random.default_rng(3)
    img = np.full((72, 128, 3), 200.0) * (1 + 0.02 * rng.standard_normal((72, 128, 1)))
    cast = img * np.array([0.8, 1.0, 1.25])
    frame = np.clip(cast, 0, 255).astype(np.uint8)
    rows, cols = cloth_samples(frame.shape[:2], np.array([64.0, 36.0]), 10.0, grid_px=4)
    gains = white_balance_gains(frame, rows, cols)
    balanced = frame[rows, cols].astype(float) * gains
    spread = np.ptp(balanced.mean(axis=0)) / balanced.mean()
    assert spread < 0.005  # the cast was 45% between B and R


def test_cloth_samples_keep_the_farthest_points_when_the_reach_covers_the_frame():
    # A long rod's reach can cover a 1280 x 720 frame: the frame's corners are still cloth.
    shape, centre = (720, 1280), np.array([639.5, 359.5])
    rows, cols = cloth_samples(shape, centre, 2000.0)
    assert rows.size == CLOTH_MIN_SAMPLES
    dist = np.hypot(cols - centre[0], rows - centre[1])
    v, u = np.mgrid[8:720:16, 8:1280:16]
    all_dist = np.sort(np.hypot(u - centre[0], v - centre[1]).ravel())
    # Exactly the farthest grid points (ties at the cut may go either way: equal distance).
    assert dist.min() >= all_dist[-CLOTH_MIN_SAMPLES]
    # Where the disc leaves enough points, the rule is the disc alone.
    rows, cols = cloth_samples(shape, centre, 300.0)
    assert rows.size > CLOTH_MIN_SAMPLES
    assert np.hypot(cols - centre[0], rows - centre[1]).min() > 300.0


def test_white_balance_leaves_out_shadows_and_clipped_samples():
    frame = np.empty((64, 64, 3), np.uint8)
    frame[:] = (160, 200, 250)  # the cloth under a cast
    rows, cols = cloth_samples(frame.shape[:2], np.array([32.0, 32.0]), 0.0, grid_px=4)
    frame[rows[::4], cols[::4]] = (10, 60, 20)  # shadowed and off-colour
    frame[rows[1::4], cols[1::4]] = (200, 230, 255)  # red clipped
    mean = np.array([160.0, 200.0, 250.0])
    want = mean.mean() / mean
    # Either kind of sample left in would move the gains by over 3%; float32 sums.
    np.testing.assert_allclose(white_balance_gains(frame, rows, cols), want / want.mean(),
                               rtol=1e-6)  # fmt: skip
    # No usable sample (black, or fewer than three): the gains do nothing.
    assert (white_balance_gains(np.zeros_like(frame), rows, cols) == 1).all()
    assert (white_balance_gains(frame, rows[2:10:4], cols[2:10:4]) == 1).all()


def test_unmixing_reads_mixing_fractions_linearly():
    red, blue, cloth = (
        np.array([45, 50, 200.0]),
        np.array([185, 80, 40.0]),
        np.array([222, 226, 230.0]),
    )
    w = unmixing_weights(red, blue, cloth)
    alpha = 0.3
    mix_rc = alpha * red + (1 - alpha) * cloth
    mix_rb = alpha * red + (1 - alpha) * blue
    img = np.array([[mix_rc, mix_rb, blue]], np.float32)
    r, b = unmixed_maps(img, w)
    np.testing.assert_allclose(r[0], [0.3, 0.3, 0.0], atol=1e-5)
    np.testing.assert_allclose(b[0], [0.0, 0.7, 1.0], atol=1e-5)
    with pytest.raises(ValueError, match="singular"):
        unmixing_weights(red, 2 * red, cloth)


def test_share_patches_equal_the_unmixed_maps_cut_out():
    """The compiled patches equal :func:`unmixed_maps` over the frame, cut at each
    corner (float32 sums in another order: within 1e-4 of values ~1)."""
    rng = np.random.default_rng(7)
    frame = rng.integers(0, 256, (60, 80, 3), dtype=np.uint8)
    w = unmixing_weights([45, 50, 200.0], [185, 80, 40.0], [222, 226, 230.0])
    tl = np.array([[0, 0], [50, 30], [13, 7]])
    which = np.array([0, 1, 1])
    got = share_patches(frame, tl, 25, w[which].astype(np.float32))
    maps = unmixed_maps(frame, w)
    for k, (u, v) in enumerate(tl):
        np.testing.assert_allclose(got[k], maps[which[k]][v : v + 25, u : u + 25], atol=1e-4)


# ------------------------------------------------------------------ pose model


def _q(dz, phi_deg, theta_deg, sx=0.0, sy=0.0):
    p, t = math.radians(phi_deg), math.radians(theta_deg)
    return np.array([dz, p * math.cos(t), p * math.sin(t), sx, sy])


def test_model_matches_plate_forward_model():
    s = Sensor()
    m = PlateModel(s)
    pose = Pose.from_degrees(0.4, 17.0, -120.0, 0.1, 0.2)
    uv, jac, rim = m.project(_q(0.4, 17.0, -120.0, 0.1, 0.2))
    fp = feature_pixels(pose, s)
    np.testing.assert_allclose(uv[:4], fp["square_corners"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(uv[4:TIP], fp["cross_arm_edges"].reshape(-1, 2), rtol=0, atol=1e-9)
    # The face centroid is not the projected disc centre (0.1-0.5 px apart at this tilt).
    gap = np.hypot(*(uv[TIP] - fp["tip"]))
    assert 0.05 < gap < 1.0
    assert jac.shape == (TIP + 1, 2, 5)


def test_polygon_centroid_of_a_square_and_triangle():
    sq = np.array([[0, 0], [2, 0], [2, 2], [0, 2.0]])
    np.testing.assert_allclose(polygon_centroid(sq), [1, 1], atol=1e-12)
    tri = np.array([[0, 0], [3, 0], [0, 3.0]])
    np.testing.assert_allclose(polygon_centroid(tri), [1, 1], atol=1e-12)
    # No area (a rim projected to one point): NaN, not an exception.
    assert np.isnan(polygon_centroid(np.ones((4, 2)))).all()


def test_polygon_area_hand_values():
    sq = np.array([[0, 0], [2, 0], [2, 2], [0, 2.0]])
    assert polygon_area(sq) == 4.0
    assert polygon_area(sq[::-1].copy()) == 4.0  # either winding
    assert polygon_area(np.array([[0, 0], [3, 0], [0, 3.0]])) == 4.5
    assert polygon_area(np.ones((4, 2))) == 0.0


@pytest.mark.parametrize("shift", [True, False])
def test_fit_recovers_pose_exactly(shift):
    m = PlateModel(Sensor())
    q = _q(0.7, 23.0, 41.0, 0.15 if shift else 0.0, -0.1 if shift else 0.0)
    uv, _, _ = m.project(q)
    offsets = np.full((TIP + 1, 2), 0.3)
    fit = fit_pose(m, uv + offsets, offsets, np.zeros(5), fit_shift=shift)
    assert fit.converged
    np.testing.assert_allclose(fit.q, q, atol=1e-9)
    assert fit.rms_px < 1e-8


def test_fit_rejects_one_outlier():
    m = PlateModel(Sensor())
    q = _q(0.2, 10.0, 100.0)
    uv, _, _ = m.project(q)
    rng = np.random.default_rng(0)
    meas = uv + 0.05 * rng.standard_normal(uv.shape)
    meas[2] += (3.0, -2.0)
    fit = fit_pose(m, meas, np.zeros_like(uv), np.zeros(5))
    assert not fit.used[2]
    assert abs(math.degrees(math.hypot(*fit.q[1:3])) - 10.0) < 0.01


@pytest.mark.parametrize("tip_move_px", [0.05, 0.5, 2.0])
def test_refit_after_the_tip_moves_matches_a_full_fit(tip_move_px):
    """One step from the fit's own Jacobian (no projection) against Gauss-Newton
    to GN_STEP_TOL: within 1e-5 rad and 2e-4 mm up to a 2 px tip move (the live
    clip's refits moved the tip < 1 px and left <= 7e-6 rad, 1.2e-4 mm)."""
    m = PlateModel(Sensor())
    q = _q(0.4, 27.0, 130.0, 0.05, -0.08)
    uv, _, _ = m.project(q)
    rng = np.random.default_rng(1)
    meas = uv + 0.05 * rng.standard_normal(uv.shape)
    meas[3] += (2.5, 1.5)  # an outlier the first fit drops, and the refit leaves out
    w = np.where(np.arange(TIP + 1) == TIP, 4.0, 1.0)
    offsets = np.zeros_like(uv)
    fit = fit_pose(m, meas, offsets, np.zeros(5), w)
    assert fit.converged and not fit.used[3]
    meas[TIP] += tip_move_px * np.array([0.6, -0.8])
    again = refit_pose(m, fit, meas, offsets, w)
    full = fit_pose(m, meas, offsets, fit.q, w * fit.used, reject_outliers=False)
    assert again.converged and not again.used[3]
    np.testing.assert_allclose(again.q[1:3], full.q[1:3], atol=1e-5)
    np.testing.assert_allclose(again.q[[0, 3, 4]], full.q[[0, 3, 4]], atol=2e-4)
    assert abs(again.rms_px - full.rms_px) < 1e-3
    # The tip moved: the refit moved q by much more than what it leaves unsolved.
    assert np.abs(again.q[1:3] - fit.q[1:3]).max() > 20 * np.abs(again.q - full.q)[1:3].max()


def test_refit_adds_the_tip_to_a_corners_only_fit():
    """After a jump the tip is measured once the corners are fitted, and added by one
    step from that fit's Jacobian (``add``): against Gauss-Newton with the tip from
    the start, within 1e-5 rad and 2e-4 mm (as a moved tip above). Without ``add``
    the tip, absent from the corners' fit, stays out."""
    m = PlateModel(Sensor())
    q = _q(0.6, 22.0, 40.0, 0.03, 0.02)
    uv, _, _ = m.project(q)
    rng = np.random.default_rng(2)
    meas = uv + 0.1 * rng.standard_normal(uv.shape)
    w = np.where(np.arange(TIP + 1) == TIP, 4.0, 1.0)
    offsets = np.zeros_like(uv)
    corners = meas.copy()
    corners[TIP] = np.nan
    fit = fit_pose(m, corners, offsets, np.zeros(5), w)
    assert fit.converged and not fit.used[TIP]
    again = refit_pose(m, fit, meas, offsets, w, add=TIP)
    full = fit_pose(m, meas, offsets, fit.q, w, reject_outliers=False)
    assert again.converged and again.used[TIP]
    np.testing.assert_allclose(again.q[1:3], full.q[1:3], atol=1e-5)
    np.testing.assert_allclose(again.q[[0, 3, 4]], full.q[[0, 3, 4]], atol=2e-4)
    assert abs(again.rms_px - full.rms_px) < 1e-3
    # The tip moved the tilt by much more than the step leaves unsolved.
    assert np.abs(again.q[1:3] - fit.q[1:3]).max() > 20 * np.abs(again.q - full.q)[1:3].max()
    kept_out = refit_pose(m, fit, meas, offsets, w)
    assert not kept_out.used[TIP]
    np.testing.assert_allclose(kept_out.q, fit.q, rtol=0, atol=1e-9)


def test_fit_with_too_few_points_is_not_converged():
    m = PlateModel(Sensor())
    meas = np.full((TIP + 1, 2), np.nan)
    meas[0] = (500, 240)
    fit = fit_pose(m, meas, np.zeros((TIP + 1, 2)), np.zeros(5))
    assert not fit.converged


# ------------------------------------------------------------------ LK


def _corner_image(shape=(90, 120), corner=(52.375, 41.625), blur=1.4):
    """A bright quadrant with its corner at ``corner`` (u, v), antialiased by 8x
    supersampling: corners must lie on the 1/8 px grid to be drawn exactly."""
    k = 8
    h, w = shape
    v, u = np.mgrid[0 : h * k, 0 : w * k]
    u = (u + 0.5) / k - 0.5
    v = (v + 0.5) / k - 0.5
    big = ((u >= corner[0]) & (v >= corner[1])).astype(np.float32)
    img = cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA)
    return cv2.GaussianBlur(img, (0, 0), blur)


def test_lk_zero_motion_is_exactly_zero():
    img = _corner_image()
    pts = np.array([[52.0, 42.0]])
    tmpl = warp_templates(img, np.zeros(2), pts, np.eye(2)[None])
    uv, quality = refine_first_template(img, np.zeros(2), tmpl, pts, np.array([True]))
    np.testing.assert_allclose(uv, pts, rtol=0, atol=1e-6)
    assert quality[0] > 0.9999


def test_lk_recovers_subpixel_shift_on_non_square_image():
    rest = _corner_image(corner=(52.375, 41.625))
    moved = _corner_image(corner=(55.0, 39.375))
    pts = np.array([[52.375, 41.625]])
    tmpl = warp_templates(rest, np.zeros(2), pts, np.eye(2)[None])
    uv, quality = refine_first_template(moved, np.zeros(2), tmpl, pts + 1.0, np.array([True]))
    np.testing.assert_allclose(uv[0], [55.0, 39.375], atol=0.02)
    assert quality[0] > 0.99


def _warped_corner_image(affine, apex, blur, size=64, k=50):
    """A corner whose edges leave ``apex`` along ``affine``'s columns, drawn sharp at k x k
    supersampling (edges placed to 1/k px), then blurred: blur after the warp, as a camera."""
    v, u = (np.mgrid[0 : size * k, 0 : size * k].astype(np.float32) + 0.5) / k - 0.5
    inv = np.linalg.inv(affine).astype(np.float32)
    du, dv = u - apex[0], v - apex[1]
    big = (((inv[0, 0] * du + inv[0, 1] * dv) >= 0) & ((inv[1, 0] * du + inv[1, 1] * dv) >= 0))
    img = cv2.resize(big.astype(np.float32), (size, size), interpolation=cv2.INTER_AREA)
    return cv2.GaussianBlur(img, (0, 0), blur)


def test_lk_without_the_apex_follows_a_tilted_blurred_corner():
    # A tilt warps the plate (foreshortening and shear); the template is the blurred rest
    # corner warped, the frame the warped corner blurred. With the apex in the fit the
    # corner moves by ~0.06 px; without it, less than a third of that. Tolerance: the
    # harness's own error, 0.007 px with no warp.
    affine = np.array([[0.92, 0.05], [0.03, 0.99]])
    apex0, apex1, inside = np.array([32.3, 31.6]), np.array([30.1, 33.4]), np.array([1.2, 1.0])
    rest = _warped_corner_image(np.eye(2), apex0, 2.5)
    moved = _warped_corner_image(affine, apex1, 2.5)
    tmpl = warp_templates(rest, np.zeros(2), (apex0 + inside)[None], affine[None])
    expect = apex1 + affine @ inside
    err = {}
    for apex_px in (0.0, 4.0):
        uv, _ = refine_first_template(moved, np.zeros(2), tmpl, expect[None] + 0.3,
                                      np.array([True]), apex_px)  # fmt: skip
        err[apex_px] = float(np.hypot(*(uv[0] - expect)))
    assert err[0.0] > 0.045
    assert err[4.0] < 0.02



def test_lk_on_the_squares_band_ignores_a_spring_in_the_far_cloth():
    # The frame has a spring's end (a bar of the cloth's level less 0.4) 7 px out from
    # both edges, inside the window, which the rest template lacks. The whole window
    # follows it by ~0.1 px; the square and an 8 px band around its edges, which its blur
    # barely reaches, by ~0.01 px. Without the spring either reads within 0.002 px.
    from camwhisker.vision.tracker import _square_band

    apex0, apex1, inside = np.array([32.3, 31.6]), np.array([33.1, 30.9]), np.array([1.2, 1.0])
    rest = _warped_corner_image(np.eye(2), apex0, 1.7)
    moved = _warped_corner_image(np.eye(2), apex1, 1.7)
    v, u = np.mgrid[0:64, 0:64]
    spring = (np.abs((u - apex1[0]) - (v - apex1[1])) < 3) & (u < apex1[0] - 7) & (
        v < apex1[1] - 7)
    moved = moved - 0.4 * cv2.GaussianBlur(spring.astype(np.float32), (0, 0), 1.7)
    tmpl = warp_templates(rest, np.zeros(2), (apex0 + inside)[None], np.eye(2)[None])
    expect = apex1 + inside
    keep = _square_band(np.eye(2)[None], tmpl.shape[1] // 2, 8.0)
    err = {}
    for label, k in (("all", None), ("band", keep)):
        uv, _ = refine_first_template(moved, np.zeros(2), tmpl, expect[None] + 0.3,
                                      np.array([True]), 4.0, k)  # fmt: skip
        err[label] = float(np.hypot(*(uv[0] - expect)))
    assert err["all"] > 0.05
    assert err["band"] < 0.02

def test_lk_float32_and_float64_inputs_agree():
    rest = _corner_image()
    moved = _corner_image(corner=(53.125, 42.25))
    pts = np.array([[52.375, 41.625]])
    tmpl = warp_templates(rest, np.zeros(2), pts, np.eye(2)[None])
    a, _ = refine_first_template(moved, np.zeros(2), tmpl, pts, np.array([True]))
    b, _ = refine_first_template(moved.astype(np.float64).astype(np.float32), np.zeros(2),
                                 tmpl.astype(np.float64).astype(np.float32), pts.astype(np.float32),
                                 np.array([True]))  # fmt: skip
    np.testing.assert_allclose(a, b, atol=1e-9)


def test_lk_inactive_points_come_back_nan():
    img = _corner_image()
    pts = np.array([[52.0, 42.0]])
    tmpl = warp_templates(img, np.zeros(2), pts, np.eye(2)[None])
    uv, q = refine_first_template(img, np.zeros(2), tmpl, pts, np.array([False]))
    assert np.isnan(uv).all() and np.isnan(q).all()


# ------------------------------------------------------------------ tip


DISC_CENTRE, DISC_RADIUS = (131.37, 96.81), 30.0


def _fine_grid(h, w, k=8):
    """Pixel coordinates (u, v) of a k-times finer grid over an h x w image."""
    v, u = np.mgrid[0 : h * k, 0 : w * k]
    return (u + 0.5) / k - 0.5, (v + 0.5) / k - 0.5


def _disc_frame():
    """A dark antialiased disc (the face) on red and blue halves, blurred 1.4 px."""
    h, w = 200, 260
    u, v = _fine_grid(h, w)
    centre = DISC_CENTRE
    disc = ((u - centre[0]) ** 2 + (v - centre[1]) ** 2 <= DISC_RADIUS**2).astype(np.float32)
    cover = cv2.resize(disc, (w, h), interpolation=cv2.INTER_AREA)[..., None]
    back = np.zeros((h, w, 3), np.float32)
    back[:, : w // 2] = (45, 50, 200)  # red on the left
    back[:, w // 2 :] = (185, 80, 40)  # blue on the right
    img = back * (1 - cover) + cover * np.array([24, 24, 26], np.float32)
    img = cv2.GaussianBlur(img, (0, 0), 1.4)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def test_tip_centre_of_a_synthetic_disc_on_two_backgrounds():
    frame, centre = _disc_frame(), DISC_CENTRE
    got = find_tip(frame, np.ones(3), np.array([120.0, 100.0]), 30.0, 20.0)
    assert got.ok
    np.testing.assert_allclose(got.centre_uv, centre, atol=0.05)
    assert got.radius_px == pytest.approx(30.0, abs=0.3)


def _polar_radius(poly, c0, at):
    """A polygon's radius about c0 in the directions ``at`` (linear in angle)."""
    a = np.arctan2(*(poly - c0).T[::-1])
    o = np.argsort(a)
    return np.interp(at, a[o], np.hypot(*(poly - c0).T)[o], period=2 * np.pi)


def test_rays_beside_the_body_are_those_any_body_direction_reaches():
    # The kernel tests only the probe directions near each ray; every one of them,
    # tested here by brute force, must give the same flags (rays set exactly on
    # probe directions included).
    rng = np.random.default_rng(1)
    ang = np.linspace(0.0, 2 * np.pi, 64, endpoint=False)
    probe = -np.pi + 2 * np.pi * np.arange(BODY_ANGLES) / BODY_ANGLES
    flagged = 0
    for trial in range(200):
        r = rng.uniform(5.0, 40.0)
        rim = np.column_stack([r * np.cos(ang), rng.uniform(0.6, 1.0) * r * np.sin(ang)])
        rim += rng.uniform(100.0, 500.0, 2)
        body = np.concatenate([rim, rim + rng.uniform(-1.5 * r, 1.5 * r, 2)])
        c0 = polygon_centroid(rim)
        on_probes = probe[rng.integers(0, BODY_ANGLES, 40)]
        ray = on_probes if trial % 2 else rng.uniform(-np.pi, np.pi, 40)
        pts = c0 + r * np.column_stack([np.cos(ray), np.sin(ray)])
        hull = cv2.convexHull(body.astype(np.float32)).reshape(-1, 2).astype(float)
        r_rim = _polar_radius(rim, c0, probe)
        shows = probe[_polar_radius(hull, c0, probe) - r_rim > BODY_PROTRUSION_PX]
        reach = BODY_BLUR_PX / r_rim.mean() + np.pi / BODY_ANGLES
        gap = np.abs((ray[:, None] - shows[None, :] + np.pi) % (2 * np.pi) - np.pi)
        want = (gap <= reach).any(axis=1)
        np.testing.assert_array_equal(_beside_body(pts, rim, body), want)
        flagged += want.sum()
    assert 0.2 < flagged / (200 * 40) < 0.8  # both answers are exercised


def _disc_beside_blue_band(band_px=3.5):
    """The face on the cloth, with a blue band ``band_px`` wide along its left half (the
    face just inside the blue square's edge), blurred 1.4 px."""
    h, w = 200, 260
    u, v = _fine_grid(h, w)
    cu, cv_ = DISC_CENTRE
    disc = (u - cu) ** 2 + (v - cv_) ** 2 <= DISC_RADIUS**2
    band = (u >= cu - DISC_RADIUS - band_px) & (u <= cu)
    colour = np.zeros((*u.shape, 3), np.float32)
    colour[:] = (215, 220, 225)  # cloth
    colour[band] = (185, 80, 40)  # blue
    colour[disc] = (24, 24, 26)  # face
    img = cv2.resize(colour, (w, h), interpolation=cv2.INTER_AREA)
    img = cv2.GaussianBlur(img, (0, 0), 1.4)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def test_tip_centre_beside_a_thin_blue_band():
    """Against blue the face's luma step is weak (blue's luma is ~0.35 of the cloth's) and
    the strong blue-to-cloth edge lies 3.5 px beyond it: rays where luma's steepest rise
    is on that edge rather than where V (the face's own edge) rises are left out, and the
    centre stays within 0.05 px (without that check: 0.66 px off, toward the band)."""
    got = find_tip(_disc_beside_blue_band(), np.ones(3), np.array([120.0, 100.0]), 30.0, 20.0)
    assert got.ok
    np.testing.assert_allclose(got.centre_uv, DISC_CENTRE, atol=0.05)


def _disc_on_cloth_and_dark_red():
    """The face on the cloth, dark red (the cross) beyond its left third, blurred 1.4 px:
    luma rises ~0.23 as steeply into the red as into the cloth."""
    h, w = 200, 260
    u, v = _fine_grid(h, w)
    cu, cv_ = DISC_CENTRE
    colour = np.zeros((*u.shape, 3), np.float32)
    colour[:] = (215, 220, 225)  # cloth
    colour[u < cu - DISC_RADIUS / 2] = (30, 35, 150)  # dark red
    colour[(u - cu) ** 2 + (v - cv_) ** 2 <= DISC_RADIUS**2] = (24, 24, 26)  # face
    img = cv2.GaussianBlur(cv2.resize(colour, (w, h), interpolation=cv2.INTER_AREA), (0, 0), 1.4)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def test_tip_centre_keeps_the_rays_into_a_dark_colour():
    """The model's rim 0.5 px smaller than the face: fitted to the whole edge, the
    shift absorbs none of it and the centre stays within 0.1 px; fitted to the cloth
    side alone (the red side's rays dropped as too weak, at MIN_RISE_FRACTION 0.3) it
    moved 0.48 px toward the cloth."""
    pts, _, why = tip_edge_points(_disc_on_cloth_and_dark_red(), np.ones(3),
                                  np.array([120.0, 100.0]), 30.0, 20.0)  # fmt: skip
    assert not why
    assert (pts[:, 0] < DISC_CENTRE[0] - 10).sum() >= N_RAYS // 3  # the red side's rays
    ang = np.linspace(0.0, 2 * np.pi, 360, endpoint=False)
    rim = np.array(DISC_CENTRE) + (DISC_RADIUS - 0.5) * np.column_stack([np.cos(ang), np.sin(ang)])
    got = rim_centre(pts, rim)
    assert got.ok
    np.testing.assert_allclose(got.centre_uv, DISC_CENTRE, atol=0.1)


def _face_on_a_dark_rod():
    """The face on red, its rod's body running 80 px to its right as dark as the
    window's usual threshold less 4 DN (a dark red rod beside the black tip), blurred
    1.4 px; and the model's rim and the rod's outline."""
    h, w = 200, 260
    u, v = _fine_grid(h, w)
    cu, cv_ = DISC_CENTRE
    colour = np.zeros((*u.shape, 3), np.float32)
    colour[:] = (45, 50, 200)  # red
    colour[(u >= cu) & (u <= cu + 80.0) & (np.abs(v - cv_) <= DISC_RADIUS)] = (16, 18, 46)
    colour[(u - cu) ** 2 + (v - cv_) ** 2 <= DISC_RADIUS**2] = (24, 24, 26)  # face
    img = cv2.GaussianBlur(cv2.resize(colour, (w, h), interpolation=cv2.INTER_AREA), (0, 0), 1.4)
    ang = np.linspace(0.0, 2 * np.pi, 360, endpoint=False)
    rim = np.array(DISC_CENTRE) + DISC_RADIUS * np.column_stack([np.cos(ang), np.sin(ang)])
    return np.clip(np.rint(img), 0, 255).astype(np.uint8), rim, np.concatenate([rim, rim + (80, 0)])


def test_tip_centre_where_a_dark_rod_joins_the_face():
    """At the usual threshold the rod's body joins the face's blob (asserted: so the
    case is the one meant); the lower threshold parts them, and the centre is within
    0.1 px (build 145's clip: a 1.05 px error at frame 70, frames 71-72 lost)."""
    frame, rim, body = _face_on_a_dark_rod()
    val, _ = brightness(frame[40:160, 70:190], np.ones(3))
    joined = _dark_blob(val, np.array([50.0, 60.0]), DISC_RADIUS, LEVEL_STEP_PX)
    assert joined[1] > JOINED_RADIUS * DISC_RADIUS
    got = find_tip(frame, np.ones(3), np.array([120.0, 100.0]), DISC_RADIUS, 20.0, rim, body)
    assert got.ok, got.reason
    np.testing.assert_allclose(got.centre_uv, DISC_CENTRE, atol=0.1)


def test_rim_scale_of_a_partial_edge_ignores_the_shift():
    """Edge points 1 % outside the model's rim, its centre 0.8 px off, on the half of
    the rim away from the rod's body (the body's side left out): the scale comes back
    to 1e-4 (the 720-gon's chords), the shift does not leak into it."""
    ang = np.linspace(-np.pi, np.pi, 720, endpoint=False)
    unit = np.column_stack([np.cos(ang), np.sin(ang)])
    c = np.array([200.0, 150.0])
    rim = c + 30.0 * unit
    body = np.concatenate([rim, rim + (-25.0, 0.0)])  # the body shows on the -u side
    rays = np.radians(np.arange(-100.0, 101.0, 7.5))
    pts = c + (0.8, -0.3) + 30.3 * np.column_stack([np.cos(rays), np.sin(rays)])
    assert rim_scale(pts, rim, body) == pytest.approx(0.01, abs=1e-4)
    # With the body on the edge's side, too few rays remain.
    assert math.isnan(rim_scale(pts, rim, np.concatenate([rim, rim + (25.0, 0.0)])))


def _face_on_cloth(blur_px: float, noise_dn: float) -> np.ndarray:
    """The face on the cloth, antialiased, blurred ``blur_px``, with Gaussian noise."""
    h, w = 200, 260
    u, v = _fine_grid(h, w)
    colour = np.zeros((*u.shape, 3), np.float32)
    colour[:] = (215, 220, 225)
    colour[(u - DISC_CENTRE[0]) ** 2 + (v - DISC_CENTRE[1]) ** 2 <= DISC_RADIUS**2] = (24, 24, 26)
    img = cv2.GaussianBlur(cv2.resize(colour, (w, h), interpolation=cv2.INTER_AREA), (0, 0),
                           blur_px)  # fmt: skip
    img += np.random.default_rng(3).normal(0.0, noise_dn, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("blur_px", [1.0, 2.0])
def test_rim_scale_takes_out_the_blur_it_measures(blur_px):
    """Blur pulls the face's edge in by ~blur^2 / (2 r): the fitted scale of a 30 px face
    is -0.10 % at 1 px and -0.21 % at 2 px. The measured blur is the true one within
    0.05 px (the pixels' own box adds 1/12 px^2; measured +0.003, +0.013), and with it
    the scale comes back within 0.05 % (measured -0.04 %, +0.02 %): 0.1 % of the rod's
    diameter moves phi by ~0.005 deg."""
    frame = _face_on_cloth(blur_px, 2.0)
    pts, _, why = tip_edge_points(frame, np.ones(3), np.array(DISC_CENTRE) + 1.0,
                                  DISC_RADIUS, 10.0)  # fmt: skip
    assert not why
    ang = np.linspace(-np.pi, np.pi, 720, endpoint=False)
    rim = np.array(DISC_CENTRE) + DISC_RADIUS * np.column_stack([np.cos(ang), np.sin(ang)])
    body = np.concatenate([rim, rim + (-25.0, 0.0)])  # the body shows on the -u side
    blur = edge_blur_px(brightness(frame, np.ones(3))[1], pts, rim, body)
    assert blur == pytest.approx(math.hypot(blur_px, 1 / math.sqrt(12)), abs=0.05)
    assert rim_scale(pts, rim, body) < -0.0005
    assert rim_scale(pts, rim, body, blur) == pytest.approx(0.0, abs=0.0005)


@pytest.mark.parametrize("angle_deg", [0, 45, 150, 270])
def test_face_near_sees_the_disc_within_one_radius_and_not_beyond_two(angle_deg):
    # V on the face is ~26 DN, on the red and blue halves >= 185 DN; with a cloth
    # level of 200 DN the dark limit is 50 DN. The 3 x 3 grid (spacing r / 2) has a
    # sample inside the face when the face is within 1.5 r of the position; at 2 r
    # the nearest sample (a diagonal one) lies 8.8 px, 6 blur sigmas, off its edge.
    frame, r = _disc_frame(), DISC_RADIUS
    d = np.array([math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))])
    c = np.array(DISC_CENTRE)
    assert face_near(frame, np.ones(3), c[None], r, 200.0)
    assert face_near(frame, np.ones(3), (c + 1.2 * r * d)[None], r, 200.0)
    assert not face_near(frame, np.ones(3), (c + 2.0 * r * d)[None], r, 200.0)
    # Any of several positions will do; positions off the frame are read at its edge.
    assert face_near(frame, np.ones(3), np.array([[-500.0, 40.0], c + 1.2 * r * d]), r, 200.0)
    assert not face_near(frame, np.ones(3), np.array([[-500.0, 40.0]]), r, 200.0)


def test_blob_statistics_equal_opencvs():
    rng = np.random.default_rng(11)
    mask = (cv2.GaussianBlur(rng.random((90, 120)), (0, 0), 3) > 0.5).astype(np.uint8)
    n, labels, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
    assert n > 3
    got = blobs(mask)
    np.testing.assert_array_equal(got.labels, labels)
    np.testing.assert_array_equal(got.area, stats[1:, cv2.CC_STAT_AREA])
    np.testing.assert_allclose(got.centroid, cents[1:], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(got.box, stats[1:, :4])
    assert len(blobs(np.zeros((5, 5), np.uint8))) == 0


def test_brightness_is_max_channel_and_luma():
    rng = np.random.default_rng(5)
    bgr = rng.integers(0, 256, (20, 30, 3), dtype=np.uint8)
    gains = np.array([0.9, 1.0, 1.1], np.float32)
    val, lum = brightness(bgr[::2, 1::3], gains)  # a strided view, as the coarse search uses
    wb = bgr[::2, 1::3].astype(np.float64) * gains
    np.testing.assert_allclose(val, wb.max(axis=2), rtol=1e-6)
    np.testing.assert_allclose(lum, wb @ [0.114, 0.587, 0.299], rtol=1e-5)


def test_tip_not_found_on_blank_frame():
    frame = np.full((200, 260, 3), 200, np.uint8)
    got = find_tip(frame, np.ones(3), np.array([120.0, 100.0]), 30.0, 20.0)
    assert not got.ok and "blob" in got.reason or "contrast" in got.reason


def test_ellipse_centre_exact_on_an_ellipse_and_none_on_a_line():
    """Noise-free points on three quarters of a tilted ellipse far from the
    origin (their mean 4.7 px from its centre): the centre to 1e-6 px. OpenCV
    fits in float32, ~1.5e-7 px here once the points are centred; uncentred it
    would return 1001.3 as 1001.29999 (1.2e-5 px off). Collinear points are
    refused, not given a centre."""
    t = np.linspace(0.0, 1.5 * np.pi, 40)
    c, s = math.cos(0.4), math.sin(0.4)
    x, y = 21.0 * np.cos(t), 13.0 * np.sin(t)
    for centre in ((612.25, 301.5), (1001.3, 707.7)):
        pts = np.column_stack([centre[0] + c * x - s * y, centre[1] + s * x + c * y])
        got = ellipse_centre(pts)
        assert got.ok
        np.testing.assert_allclose(got.centre_uv, centre, rtol=0, atol=1e-6)
        assert got.radius_px == pytest.approx(17.0, abs=1e-4)
    t = np.linspace(0.0, 2 * np.pi, 40, endpoint=False)
    for line in (np.column_stack([t, 2 * t]), np.column_stack([t, np.zeros_like(t)])):
        assert not ellipse_centre(600.0 + line).ok


# ------------------------------------------------------------------ bench


def test_bench_errors_and_table():
    from camwhisker.bench.vision import BenchRow, _errors, table
    from camwhisker.sim.render.scenarios import PoseTrack

    z = np.zeros(4)
    truth = PoseTrack(np.arange(4.0), np.array([0, 0.5, 0.5, 1.0]), np.array([0, 1, 20, 30.0]),
                      np.array([0, 10, 179, -170.0]), z, z)  # fmt: skip
    dz = truth.dz_mm + [0, 0.01, -0.01, 0.0]
    phi = truth.phi_deg + [0, 0.0, 0.1, 0.3]
    theta = np.array([np.nan, 10.0, -179.0, -171.0])  # errors wrap: 2 and 1 deg
    ok = np.array([True, True, True, False])
    phi_rmse, dz_rmse, theta_mae, bias = _errors(truth, dz, phi, theta, ok)
    assert phi_rmse == pytest.approx(math.sqrt(0.01 / 3))
    assert dz_rmse == pytest.approx(math.sqrt(0.0002 / 3))
    assert theta_mae == pytest.approx(2.0)  # only phi >= 2 deg and ok: frame 2
    assert bias == pytest.approx(0.1)
    text = table([BenchRow("nominal", "model", 4, 100.0, 120.0, 0.75, phi_rmse, dz_rmse,
                           theta_mae, bias)])  # fmt: skip
    assert "| nominal | model | 4 | 100 | 120 | 75% |" in text


def test_occlusion_tests_every_point_near_the_polygon():
    # The occlusion check runs OpenCV's point-polygon distance only on the points near
    # the polygon's box: none it skips may lie within reach (exact: a skipped point is
    # over reach + 1 px from the box, so from the polygon).
    from camwhisker.vision.tracker import _near_box

    rng = np.random.default_rng(3)
    reach, hits = 20.0, 0
    for _ in range(200):
        poly = cv2.convexHull((rng.uniform(0, 60, (8, 2)) + rng.uniform(200, 400, 2))
                              .astype(np.float32))  # fmt: skip
        uv = rng.uniform(150, 500, (12, 2))
        uv[0] = np.nan  # a lost point is tested, as before the box
        near = set(_near_box(uv.tolist(), poly, reach))
        inside = {k for k in range(1, 12)
                  if cv2.pointPolygonTest(poly, uv[k].tolist(), True) > -reach}  # fmt: skip
        assert inside <= near and 0 in near
        hits += len(inside)
    assert hits > 50  # the draw put points within reach often enough to mean something
