"""Scenarios, artefacts and real video files with their truth."""

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest

from camwhisker.sensor.file import Sensor, load_sensor
from camwhisker.sensor.plate import Pose, feature_pixels
from camwhisker.sim.render.artefacts import Artefacts, apply_artefacts, jpeg_roundtrip
from camwhisker.sim.render.samples import describe_video
from camwhisker.sim.render.scenarios import SCENARIOS, PoseTrack, make_scenario
from camwhisker.sim.render.video import render_frames, render_scenario, write_video


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_scenarios_stay_in_range(name):
    sc = make_scenario(name, 40, seed=5)
    tr = sc.track
    assert len(tr) == 40
    assert tr.phi_deg.min() >= 0 and tr.phi_deg.max() <= 35.0 + 1e-9
    assert tr.dz_mm.min() >= 0 and tr.dz_mm.max() <= 1.0 + 1e-9
    assert (tr.theta_deg > -180).all() and (tr.theta_deg <= 180).all()
    assert tr.phi_deg[0] == 0 and tr.dz_mm[0] == 0  # first frame is the rest reference
    assert np.diff(tr.t_s) == pytest.approx(np.full(39, 1 / 30))


def test_same_seed_same_scenario_other_seed_other():
    a, b, c = (make_scenario("nominal", 50, s).track for s in (1, 1, 2))
    assert np.array_equal(a.phi_deg, b.phi_deg)
    assert not np.array_equal(a.phi_deg, c.phi_deg)


def test_nominal_has_holds_and_reaches_the_range():
    tr = make_scenario("nominal", 200, seed=9).track
    held = np.sum((np.diff(tr.phi_deg) == 0) & (tr.phi_deg[1:] > 0))
    assert held >= 50  # 40% of frames in holds of 4 frames: 3 repeats per hold
    assert tr.phi_deg.max() > 25 and tr.dz_mm.max() > 0.9


def test_hard_cases_do_what_they_say():
    sensor = Sensor()
    oof = make_scenario("out_of_frame", 20, 0).track
    corners = feature_pixels(oof.pose(19), sensor)["square_corners"]
    assert corners[:, 1].max() > sensor.camera.height_px - 1  # square leaves the frame
    tip = make_scenario("tip_crossing", 20, 0).track
    px = feature_pixels(tip.pose(19), sensor)
    assert px["tip"][0] > px["square_corners"][:, 0].max()  # tip beyond the right edge
    assert make_scenario("large_tilt", 20, 0).track.phi_deg.max() == pytest.approx(35.0)


def test_unknown_scenario_is_named():
    with pytest.raises(ValueError, match="'bogus'"):
        make_scenario("bogus", 10, 0)


def test_artefacts_do_not_touch_the_scene_and_noise_has_its_level():
    scene = np.full((200, 300, 3), 128.0, np.float32)
    before = scene.copy()
    art = Artefacts(noise_dn=3.0)
    out = apply_artefacts(scene, 0.0, art, np.random.default_rng(0))
    assert np.array_equal(scene, before)
    # At mid grey the noise sd is noise_dn, plus 1/12 DN^2 of rounding.
    assert out.astype(float).std() == pytest.approx(np.sqrt(9 + 1 / 12), rel=0.02)
    cast = apply_artefacts(
        scene, 0.0, Artefacts(cast_bgr=(0.8, 1.0, 1.2)), np.random.default_rng(0)
    )
    assert tuple(cast[0, 0]) == (102, 128, 154)


def test_lighting_jump_and_saturation():
    scene = np.full((10, 10, 3), 200.0, np.float32)
    art = Artefacts(lighting_jump=(1.0, 0.7), gain=1.4)
    rng = np.random.default_rng(0)
    assert apply_artefacts(scene, 0.5, art, rng).max() == 255  # 280 clips
    assert apply_artefacts(scene, 1.5, art, rng)[0, 0, 0] == 196  # 200 * 1.4 * 0.7


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    out = tmp_path_factory.mktemp("video")
    sc = make_scenario("distortion", 6, seed=11)
    return sc, render_scenario(sc, Sensor(), out / "clip.avi", seed=11)


def test_render_scenario_writes_video_truth_sensor_and_metadata(rendered):
    sc, paths = rendered
    info = describe_video(paths["video"])
    assert info["frames_decoded"] == 6
    assert (info["width_px"], info["height_px"]) == (1280, 720)
    truth = PoseTrack.read_csv(paths["truth"])
    assert np.allclose(truth.phi_deg, sc.track.phi_deg, atol=1e-6)
    sensor = load_sensor(paths["sensor"])
    assert sensor.camera.distortion[0] == -0.28 and sensor.camera.cx_px == 618.3
    meta = json.loads(paths["meta"].read_text())
    assert meta["scenario"] == "distortion" and meta["seed"] == 11 and meta["codec"] == "MJPG"


def test_mjpg_frames_decode_close_to_the_camera_frames(rendered):
    sc, paths = rendered
    raw = list(render_frames(sc, Sensor(), seed=11))
    cap = cv2.VideoCapture(str(paths["video"]))
    diffs = []
    for frame in raw:
        ok, decoded = cap.read()
        assert ok
        diffs.append(np.abs(decoded.astype(float) - frame).mean())
    # JPEG at quality 88 on a noisy frame: ~1-2 DN mean error, far below the features' contrast.
    assert 0.2 < np.mean(diffs) < 3.0
    again = next(iter(render_frames(sc, Sensor(), seed=11)))
    assert np.array_equal(again, raw[0])  # reproducible bit for bit


def test_mp4_round_trip(tmp_path):
    frames = [np.full((64, 96, 3), v, np.uint8) for v in (40, 120, 200)]
    n = write_video(tmp_path / "x.mp4", frames, 30.0)
    cap = cv2.VideoCapture(str(tmp_path / "x.mp4"))
    means = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        means.append(f.mean())
    assert n == 3 and means == pytest.approx([40, 120, 200], abs=1.0)  # 8-bit YUV rounding


def test_failed_render_leaves_no_file(tmp_path):
    def frames():
        yield np.zeros((64, 96, 3), np.uint8)
        raise RuntimeError("renderer crashed")

    with pytest.raises(RuntimeError, match="crashed"):
        write_video(tmp_path / "x.avi", frames(), 30.0)
    assert list(tmp_path.iterdir()) == []


def test_jpeg_roundtrip_quality_orders_error():
    rng = np.random.default_rng(0)
    img = np.clip(128 + 20 * rng.standard_normal((64, 64, 3)), 0, 255).astype(np.uint8)
    err = {q: np.abs(jpeg_roundtrip(img, q).astype(float) - img).mean() for q in (50, 95)}
    assert err[95] < err[50]


def test_out_of_range_pose_renders_without_warnings():
    # The plate pushed far sideways: most features out of frame, no NaN, no warning.
    from camwhisker.sim.render.render import SceneRenderer

    img = SceneRenderer(Sensor()).geometry(Pose(sx_mm=30.0))
    assert np.isfinite(img).all()
    scene = replace(make_scenario("nominal", 10, 0), name="x")
    assert scene.name == "x"


def test_bundled_sample_regenerates_bit_for_bit(tmp_path):
    from pathlib import Path

    from camwhisker.sim.render.samples import SAMPLES

    bundled = Path(__file__).resolve().parents[1] / "sample_frames"
    sample = next(s for s in SAMPLES if s.file.endswith(".avi"))  # the shortest clip
    sc = make_scenario(sample.scenario, sample.frames, sample.seed)
    paths = render_scenario(sc, Sensor(), tmp_path / sample.file, sample.seed)
    for path in paths.values():
        assert path.read_bytes() == (bundled / path.name).read_bytes(), path.name
