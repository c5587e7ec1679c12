"""Hand-made builds: reproducible draws within tolerance, the optional sensor-file
keys, and the renderer and forward model on a build."""

from __future__ import annotations

import math

import numpy as np
import pytest

from camwhisker.sensor.file import (
    OPTIONAL_PLATE_KEYS,
    Sensor,
    SensorFileError,
    dump_sensor,
    load_sensor,
    sensor_to_dict,
)
from camwhisker.sensor.plate import Pose, cross_outline, rod_ends, square_corners
from camwhisker.sim.render.builds import REALITY_SUITE, TOLERANCES, draw_build
from camwhisker.sim.render.render import Appearance, SceneRenderer

NOMINAL = Sensor()
POSE = Pose.from_degrees(0.3, 14.0, 35.0)


def test_draws_are_reproducible_and_differ_by_seed():
    assert draw_build(7).describe() == draw_build(7).describe()
    assert draw_build(7).describe() != draw_build(8).describe()


def test_every_deviation_lies_within_its_tolerance():
    tol, cam, pl = TOLERANCES, NOMINAL.camera, NOMINAL.plate
    eps = 1e-9
    for seed in range(200):
        b = draw_build(seed)
        c, p = b.sensor.camera, b.sensor.plate
        assert abs(c.fx_px / cam.fx_px - 1) <= tol["fx_rel"] + eps
        assert abs(c.fy_px / cam.fy_px - 1) <= tol["fy_rel"] + eps
        assert abs(c.cx_px - cam.cx_px) <= tol["cx_px"] + eps
        assert abs(c.cy_px - cam.cy_px) <= tol["cy_px"] + eps
        assert abs(c.distortion[0]) <= tol["k1"] + eps
        assert c.distortion[1:] == cam.distortion[1:]
        assert abs(p.z_i_mm - pl.z_i_mm) <= tol["z_i_mm"] + eps
        assert abs(p.h_r_mm - pl.h_r_mm) <= tol["h_r_mm"] + eps
        for key in ("square_side_mm", "cross_span_mm", "cross_arm_mm", "rod_diameter_mm"):
            assert abs(getattr(p, key) - getattr(pl, key)) <= tol["size_mm"] + eps
        for key in ("square_offset_mm", "cross_offset_mm"):
            assert abs(getattr(p, key) - getattr(pl, key)) <= tol["depth_offset_mm"] + eps
        rod_mm = p.h_r_mm - p.cross_offset_mm
        tilt = math.degrees(math.atan2(math.hypot(p.tip_offset_x_mm, p.tip_offset_y_mm), rod_mm))
        assert tilt <= tol["rod_tilt_deg"] + eps
        for f in ("square", "cross"):
            shift = math.hypot(getattr(p, f"{f}_shift_x_mm"), getattr(p, f"{f}_shift_y_mm"))
            assert shift <= tol["feature_shift_mm"] + eps
            assert abs(getattr(p, f"{f}_rotation_deg")) <= tol["feature_rotation_deg"] + eps


def test_suite_keeps_tuning_and_held_out_seeds_apart():
    assert not set(REALITY_SUITE.tuning_seeds) & set(REALITY_SUITE.held_out_seeds)
    assert len(REALITY_SUITE.held_out_seeds) >= 20


def test_a_nominal_file_with_zero_optional_keys_renders_bit_identically(tmp_path):
    path = tmp_path / "zeros.toml"
    path.write_text("[plate]\n" + "".join(f"{k} = 0.0\n" for k in OPTIONAL_PLATE_KEYS))
    zeros = load_sensor(path)
    assert not set(OPTIONAL_PLATE_KEYS) & set(sensor_to_dict(NOMINAL)["plate"])
    assert dump_sensor(zeros).split("\n", 1)[1] == dump_sensor(NOMINAL).split("\n", 1)[1]
    plain = SceneRenderer(NOMINAL).geometry(POSE)
    assert np.array_equal(SceneRenderer(zeros, Appearance()).geometry(POSE), plain)


def test_a_builds_true_file_round_trips(tmp_path):
    for seed in REALITY_SUITE.tuning_seeds:
        b = draw_build(seed)
        path = tmp_path / f"build{seed}.toml"
        path.write_text(dump_sensor(b.sensor))
        back = load_sensor(path)
        assert back.camera == b.sensor.camera
        assert back.plate == b.sensor.plate
        assert back.whisker == b.sensor.whisker


@pytest.mark.parametrize(
    "line, key",
    [
        ('tip_offset_x_mm = "0.1"', "tip_offset_x_mm"),
        ("tip_offset_y_mm = 2.0", "tip_offset_y_mm"),
        ("square_shift_x_mm = 1.5", "square_shift_x_mm"),
        ("cross_shift_y_mm = -1.2", "cross_shift_y_mm"),
        ("square_rotation_deg = 12.0", "square_rotation_deg"),
        ("cross_rotation_deg = nan", "cross_rotation_deg"),
        ("cross_shift_x_mm = true", "cross_shift_x_mm"),
    ],
)
def test_optional_keys_reject_bad_values_naming_file_and_key(tmp_path, line, key):
    path = tmp_path / "bad.toml"
    path.write_text(f"[plate]\n{line}\n")
    with pytest.raises(SensorFileError) as err:
        load_sensor(path)
    assert str(path) in str(err.value)
    assert key in str(err.value)


def test_optional_keys_place_the_features():
    plate = NOMINAL.replace(
        plate={
            "square_shift_x_mm": 0.2,
            "square_rotation_deg": 90.0 / 9,
            "cross_shift_y_mm": -0.1,
            "cross_rotation_deg": -3.0,
            "tip_offset_x_mm": 0.15,
            "tip_offset_y_mm": -0.05,
        }
    ).plate
    sq = square_corners(plate)
    assert np.allclose(sq.mean(axis=0), [0.2, 0.0, plate.square_offset_mm])
    side = np.linalg.norm(sq[1] - sq[0])
    assert side == pytest.approx(plate.square_side_mm)
    edge = sq[1] - sq[0]
    assert math.degrees(math.atan2(edge[1], edge[0])) == pytest.approx(10.0)
    assert np.allclose(cross_outline(plate).mean(axis=0), [0.0, -0.1, -plate.cross_offset_mm])
    base, tip = rod_ends(plate)
    assert np.allclose(base, [0.0, -0.1, -plate.cross_offset_mm])
    assert np.allclose(tip, [0.15, -0.15, -plate.h_r_mm])


def test_a_build_renders_its_own_geometry():
    """The rendered end face's centroid lies where the build's model puts the tip."""
    from camwhisker.sensor.model import TIP, PlateModel

    b = draw_build(REALITY_SUITE.tuning_seeds[1])
    r = SceneRenderer(b.sensor, Appearance())  # plain colours: the tip is the darkest blob
    img = r.geometry(POSE)
    q = np.array([POSE.dz_mm, POSE.phi_rad * math.cos(POSE.theta_rad),
                  POSE.phi_rad * math.sin(POSE.theta_rad), 0.0, 0.0])  # fmt: skip
    tip_uv = PlateModel(b.sensor).project(q, jacobian=False)[0][TIP]
    u0, v0 = np.round(tip_uv).astype(int) - 40
    patch = img[v0 : v0 + 81, u0 : u0 + 81].max(axis=2)  # only the tip is dark in all
    weight = np.clip((70.0 - patch) / (70.0 - 26.0), 0.0, 1.0)
    vv, uu = np.mgrid[0:81, 0:81]
    centroid = np.array([(weight * uu).sum(), (weight * vv).sum()]) / weight.sum()
    # A rod drawn untilted would put it ~10 px away; 0.3 px allows for the flanks.
    assert np.hypot(*(centroid + [u0, v0] - tip_uv)) < 0.3


#: Detection at the rest frame against the truth: under blur a corner is found a
#: few pixels inside it (up to 2.6 px on the nominal scene; the rest reference
#: absorbs it); the tip's end face is fitted with the model's rim.
CORNER_TOL_PX = 6.0
TIP_TOL_PX = 0.6


def _first_frame(build):
    from camwhisker.sim.render.artefacts import jpeg_roundtrip
    from camwhisker.sim.render.scenarios import make_scenario
    from camwhisker.sim.render.video import render_frames

    scenario = build.scenario(make_scenario("nominal", 10, build.seed))
    frame = next(render_frames(scenario, build.sensor, build.seed, appearance=build.appearance))
    return jpeg_roundtrip(frame, build.webcam["jpeg_quality"])


@pytest.mark.parametrize("seed", REALITY_SUITE.held_out_seeds[:3])
def test_detection_finds_a_held_out_builds_features(seed):
    from camwhisker.sensor.model import TIP, PlateModel
    from camwhisker.vision.detect import detect_features
    from camwhisker.vision.tracker import FrontEnd

    build = draw_build(seed)
    frame = _first_frame(build)
    fe = FrontEnd(build.sensor)
    det = detect_features(frame, fe.gains(frame), fe.model)
    truth = PlateModel(build.sensor).project(np.zeros(5), jacobian=False)[0]
    err = np.hypot(*(det.uv - truth).T)
    assert err[:TIP].max() < CORNER_TOL_PX
    assert err[TIP] < TIP_TOL_PX


def test_a_pale_cross_on_tinted_cloth_still_gives_the_rest_colours():
    """Build 126's yellow cloth, white balanced to grey, leaves its cross at |G| ~ 1.0,
    at the fixed threshold: the cross's core comes from its own extreme instead."""
    from camwhisker.vision.colour import contrast_map
    from camwhisker.vision.rest import COLOUR_G_MIN, colour_core
    from camwhisker.vision.tracker import FrontEnd

    build = draw_build(126)
    frame = _first_frame(build)
    fe = FrontEnd(build.sensor)
    fe.start(frame)  # raised "features not found: cross colour" before
    rest = fe.rest
    u0, v0 = rest.origin.astype(int)
    g = contrast_map(frame[v0 : v0 + rest.region_size[1], u0 : u0 + rest.region_size[0]],
                     rest.gains)  # fmt: skip
    cross, square = colour_core(-g), colour_core(g)
    assert np.percentile(-g, 99) < 1.1 * COLOUR_G_MIN  # the case: a cross this pale
    # The two cores unmix apart: 0.05 is ~10x the shares' scatter at this noise.
    assert np.median(rest.red[cross]) == pytest.approx(1.0, abs=0.05)
    assert np.median(rest.red[square]) == pytest.approx(0.0, abs=0.05)
    assert np.median(rest.blue[cross]) == pytest.approx(0.0, abs=0.05)


def test_an_absent_colour_has_no_core():
    from camwhisker.vision.rest import colour_core

    rng = np.random.default_rng(0)
    g = rng.normal(0.0, 0.1, (200, 200)).astype(np.float32)  # cloth: noise about G = 0
    g[50:120, 60:150] = 1.9 + rng.normal(0.0, 0.03, (70, 90))  # the square
    assert not colour_core(-g).any()
    # Eroded by 4 px: (70 - 8) x (90 - 8) pixels of the square.
    assert colour_core(g).sum() == 62 * 82


def test_a_failed_detection_says_what_was_found_and_where():
    from camwhisker.vision.detect import FeaturesNotFound, detect_features
    from camwhisker.vision.tracker import FrontEnd

    build = draw_build(REALITY_SUITE.tuning_seeds[0])
    frame = _first_frame(build)
    frame[:, 700:] = frame[0, 0]  # the cloth over the features' right half
    fe = FrontEnd(build.sensor)
    with pytest.raises(FeaturesNotFound) as err:
        detect_features(frame, fe.gains(frame), fe.model)
    msg = str(err.value)
    assert "square corners" in msg and "expected near" in msg and "blue regions" in msg


def test_the_models_geometry_jacobian_holds_on_a_build():
    """The optional keys join the model's geometry with exact derivatives."""
    from camwhisker.sensor.model import (
        GEOMETRY_NAMES,
        PlateModel,
        geometry_vector,
        with_geometry,
    )

    sensor = draw_build(REALITY_SUITE.tuning_seeds[2]).sensor
    p, t = math.radians(21.0), math.radians(-50.0)
    q = np.array([0.3, p * math.cos(t), p * math.sin(t), 0.05, -0.1])
    jac = PlateModel(sensor).jacobians(q).geometry
    g0, h = geometry_vector(sensor), 1e-3
    for i in range(len(GEOMETRY_NAMES)):
        up, down = g0.copy(), g0.copy()
        up[i] += h
        down[i] -= h
        uv_up = PlateModel(with_geometry(sensor, up)).project(q, jacobian=False)[0]
        uv_down = PlateModel(with_geometry(sensor, down)).project(q, jacobian=False)[0]
        numeric = (uv_up - uv_down) / (2 * h)
        assert np.abs(jac[:, :, i] - numeric).max() <= 1e-6 * np.abs(jac[:, :, i]).max() + 1e-7
