"""The features file: rough rest positions from the user where detection fails.

The scene: a nominal frame at rest whose cross has a light centre 1.8 mm across
(a hand-made build's unpainted centre, within the reality suite's 1.2-1.8 mm),
which splits the cross into its four arms. Detection pieces the arms together
around where the sensor file's model puts the cross; a file whose principal
point is off by OFF_PX puts it there wrongly, and only a hint finds it.

| check | expectation | reason |
|---|---|---|
| correct file, no hints | 13 points found | the scene is detectable |
| file off by OFF_PX, no hints | cross arm ends missing; names --features | arms beyond the reach |
| ... hints HINT_ERROR_PX off | within SAME_GAINS_PX of the correct file's | same gains |
| ... through FrontEnd.start | within START_PX of the correct file's | gains move with cx, cy |
| no, empty, at-model hints | bit-identical points | un-hinted search unchanged |
| bad files | FeatureHintsError naming file and key | the sensor file's rules |
| batch with / without --features | 4 ok rows, phi < 0.05 deg / exit 2, no file | the way out |
| overlay --features; live, replay | 4 ok frames, hints in the sidecar / parsed | every rest start |
| calibrate-sensor's rest tip radius, wrong file | fails / hints: within 0.01 px | its first start |

(A principal point only translates the model's image, so with the same gains
the same edges give the same corners.)
"""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from camwhisker.cli import main
from camwhisker.cli.parser import build_parser
from camwhisker.io.video_out import write_video
from camwhisker.sensor.file import Sensor, dump_sensor
from camwhisker.sensor.model import N_SQUARE, TIP, PlateModel
from camwhisker.sensor.plate import Pose
from camwhisker.sim.render.artefacts import apply_artefacts, illumination_field, jpeg_roundtrip
from camwhisker.sim.render.render import Appearance, SceneRenderer
from camwhisker.sim.render.scenarios import NOMINAL_ARTEFACTS
from camwhisker.vision import FeaturesNotFound, FrontEnd, FrontEndOptions
from camwhisker.vision.colour import white_balance_gains
from camwhisker.vision.detect import WAY_OUT, detect_features
from camwhisker.vision.hints import FeatureHints, FeatureHintsError, load_feature_hints

SENSOR = Sensor()
#: The wrong file's principal point offset (px): ~108 px, past the cross's merge reach.
OFF_PX = (100.0, 40.0)
OFF = SENSOR.replace(camera={"cx_px": 639.5 + OFF_PX[0], "cy_px": 359.5 + OFF_PX[1]})
#: How far the hints lie from the true centres (px): read off an image by eye.
HINT_ERROR_PX = np.array([4.0, -3.0])
#: Same frame, same gains: measured 0.000 px for the corners, 0.001 px for the tip
#: (its rim is placed at the found centre from the model's).
SAME_GAINS_PX = 0.01
#: Through FrontEnd.start: measured 0.20-0.45 px over render seeds 0-2 and four
#: offsets of ~100 px (the white balance's cloth samples move with cx, cy).
START_PX = 0.6
LIGHT_CENTRE = Appearance(cross_centre_bgr=(200.0, 200.0, 200.0), cross_centre_diameter_mm=1.8)
ALL = ("square corners", "cross arm ends", "magnifier tip")
FRAME_SIZE = (1280, 720)


def _frames(renderer, n, seed, pose=None):
    """n frames at ``pose`` (default rest) with fresh noise, as the webcam's MJPG gives them."""
    art = NOMINAL_ARTEFACTS
    rng = np.random.default_rng(seed)
    light = illumination_field(renderer.shape, art)
    scene = renderer.geometry(pose or Pose())
    return [jpeg_roundtrip(apply_artefacts(scene, i / 30, art, rng, light), art.jpeg_quality)
            for i in range(n)]  # fmt: skip


@pytest.fixture(scope="module")
def renderer():
    return SceneRenderer(SENSOR, LIGHT_CENTRE)


@pytest.fixture(scope="module")
def frame(renderer):
    return _frames(renderer, 1, seed=20)[0]


def _true_hints(**keep) -> FeatureHints:
    """Hints HINT_ERROR_PX off the features' true rest centres (the correct file's model)."""
    uv = PlateModel(SENSOR).project(np.zeros(5), jacobian=False)[0]
    centres = {"square_centre_px": uv[:N_SQUARE].mean(axis=0),
               "cross_centre_px": uv[N_SQUARE:TIP].mean(axis=0), "tip_px": uv[TIP]}  # fmt: skip
    return FeatureHints(**{k: tuple(c + HINT_ERROR_PX) for k, c in centres.items()
                           if keep.get(k, True)})  # fmt: skip


def _gains(frame):
    return white_balance_gains(frame, *FrontEnd(SENSOR)._cloth)


def test_the_wrong_file_misses_the_split_cross(frame):
    gains = _gains(frame)
    assert detect_features(frame, gains, PlateModel(SENSOR)).found.all()
    with pytest.raises(FeaturesNotFound) as err:
        FrontEnd(OFF).start(frame)
    assert err.value.missing == ["cross arm ends"]
    assert str(err.value).endswith("; " + WAY_OUT) and "--features FILE" in WAY_OUT


@pytest.mark.parametrize("only_cross", [False, True])
def test_hints_find_what_the_model_misses(frame, only_cross):
    gains = _gains(frame)
    truth = detect_features(frame, gains, PlateModel(SENSOR)).uv
    hints = _true_hints(square_centre_px=not only_cross, tip_px=not only_cross)
    uv = detect_features(frame, gains, PlateModel(OFF), hints=hints).uv
    assert np.hypot(*(uv - truth).T).max() < SAME_GAINS_PX


def test_front_end_starts_with_hints_in_its_options(frame):
    truth = FrontEnd(SENSOR)
    truth.start(frame)
    fe = FrontEnd(OFF, FrontEndOptions(features=_true_hints()))
    fe.start(frame)
    assert np.hypot(*(fe.rest.uv - truth.rest.uv).T).max() < START_PX
    # Tracked at rest, no corner is taken for hidden: the rod's and the cross's
    # outlines are placed where the rest points are, not where the file puts them.
    r = fe.update(frame)
    assert r.ok and r.n_corners == TIP


def test_no_hints_leave_detection_bit_identical():
    # A tilted nominal frame, searched from the rest pose with nothing required (the
    # tracker's re-detection), where the model's positions matter most.
    image = _frames(SceneRenderer(SENSOR), 1, seed=3, pose=Pose.from_degrees(0.3, 12.0, 40.0))[0]
    gains, model = _gains(image), PlateModel(SENSOR)
    uv = model.project(np.zeros(5), jacobian=False)[0]
    at_model = FeatureHints(tuple(uv[:N_SQUARE].mean(axis=0)), tuple(uv[N_SQUARE:TIP].mean(axis=0)),
                            tuple(uv[TIP]))  # fmt: skip
    base = detect_features(image, gains, model, require=()).uv
    assert np.isfinite(base).all(axis=1).sum() >= 9  # something to compare
    for hints in (FeatureHints(), at_model):
        again = detect_features(image, gains, model, require=(), hints=hints).uv
        assert np.array_equal(again, base, equal_nan=True)


@pytest.mark.parametrize(
    ("text", "key", "says"),
    [
        ("[features]\ncentre_px = [1.0, 2.0]\n", "centre_px", "unknown key"),
        ('[features]\ntip_px = "here"\n', "tip_px", "[u, v]"),
        ("[features]\ntip_px = [1.0, 2.0, 3.0]\n", "tip_px", "[u, v]"),
        ("[features]\ncross_centre_px = [true, 2.0]\n", "cross_centre_px", "expected numbers"),
        ("[features]\ntip_px = [nan, 300.0]\n", "tip_px", "finite"),
        ("[features]\nsquare_centre_px = [1280.0, 10.0]\n", "square_centre_px", "outside"),
        ("[features]\nsquare_centre_px = [10.0, -1.0]\n", "square_centre_px", "outside"),
        ("[feature]\ntip_px = [1.0, 2.0]\n", "[feature]", "unknown table"),
        ("tip_px = [1.0, 2.0]\n", "tip_px", "unknown table"),
        ("# nothing\n", "[features]", "no [features] table"),
        ("[features\n", "", "not valid TOML"),
    ],
)
def test_bad_files_name_file_and_key(tmp_path, text, key, says):
    path = tmp_path / "hints.toml"
    path.write_text(text)
    with pytest.raises(FeatureHintsError) as err:
        load_feature_hints(path, FRAME_SIZE)
    assert str(err.value).startswith(f"{path}: ") and key in str(err.value)
    assert says in str(err.value)


def test_a_good_file_reads_back(tmp_path):
    path = tmp_path / "hints.toml"
    path.write_text("[features]\ncross_centre_px = [640, 360.5]\n")
    hints = load_feature_hints(path, FRAME_SIZE)
    assert hints == FeatureHints(cross_centre_px=(640.0, 360.5), source=str(path))
    with pytest.raises(FeatureHintsError, match="cannot read"):
        load_feature_hints(tmp_path / "none.toml", FRAME_SIZE)


@pytest.fixture(scope="module")
def clip(renderer, tmp_path_factory):
    """4 frames at rest as an MJPG video, the wrong sensor file and a features file."""
    d = tmp_path_factory.mktemp("hints")
    write_video(d / "rest.avi", _frames(renderer, 4, seed=21), 30.0)
    (d / "off.toml").write_text(dump_sensor(OFF))
    h = _true_hints()
    (d / "hints.toml").write_text(
        "[features]\n" + "".join(f"{k} = [{v[0]:.1f}, {v[1]:.1f}]\n"
                                 for k, v in [("square_centre_px", h.square_centre_px),
                                              ("cross_centre_px", h.cross_centre_px),
                                              ("tip_px", h.tip_px)])  # fmt: skip
    )
    return d


def test_batch_with_and_without_features(clip, tmp_path, capsys):
    out = tmp_path / "sig.csv"
    base = ["batch", str(clip / "rest.avi"), "--sensor", str(clip / "off.toml"), "--out", str(out),
            "--quiet"]  # fmt: skip
    assert main(base) == 2
    err = capsys.readouterr().err
    assert err.startswith("camwhisker batch: error: features not found: cross arm ends")
    assert "--features FILE" in err
    assert not out.exists() and not list(tmp_path.iterdir())
    assert main(base + ["--features", str(clip / "hints.toml")]) == 0
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    # At rest: every row trusted, phi near zero (the rest offsets absorb the file's
    # error; measured <= 0.004 deg).
    assert len(rows) == 4 and all(r["ok"] == "1" for r in rows)
    assert max(abs(float(r["phi_deg"])) for r in rows) < 0.05
    meta = json.loads((tmp_path / "sig.json").read_text())
    assert meta["rest_frames_used"] == 4  # the mean image is detected with the hints too
    features = meta["options"]["features"]
    assert features["source"] == str(clip / "hints.toml")
    # The file holds one decimal: within 0.05 px of the hints it was written from.
    np.testing.assert_allclose(features["cross_centre_px"],
                               _true_hints().cross_centre_px, atol=0.05)  # fmt: skip


def test_overlay_takes_features_and_the_live_commands_parse_it(clip, tmp_path):
    out = tmp_path / "ann.avi"
    hints = str(clip / "hints.toml")
    argv = ["overlay", str(clip / "rest.avi"), "--sensor", str(clip / "off.toml"), "--out",
            str(out), "--features", hints, "--quiet"]  # fmt: skip
    assert main(argv) == 0
    meta = json.loads((tmp_path / "ann.overlay.json").read_text())
    assert meta["frames_ok"] == 4 and meta["options"]["features"]["source"] == hints
    parser = build_parser()
    for argv in (["live", "0", "--out", "x.csv"], ["replay", "s.avi", "--out", "x.csv"]):
        assert parser.parse_args(argv + ["--features", hints]).features == hints


def test_batch_names_a_bad_features_file(clip, tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[features]\ntip_px = [2000.0, 10.0]\n")
    out = tmp_path / "sig.csv"
    argv = ["batch", str(clip / "rest.avi"), "--out", str(out), "--features", str(bad)]
    assert main(argv) == 2
    assert capsys.readouterr().err.startswith(f"camwhisker batch: error: {bad}: [features] tip_px")
    assert not out.exists()


def test_calibrate_sensor_starts_its_sweep_with_the_hints(clip):
    """calibrate-sensor's first step, the tip's radius at rest, starts the front end on the
    sweep's first frame: with the wrong file it fails without hints and, with them, measures
    the radius the correct file gives (the same edge points; 0.01 px covers the gains)."""
    from camwhisker.calibration.sweep import rest_tip_radius_px

    video = clip / "rest.avi"
    with pytest.raises(FeaturesNotFound, match="cross arm ends"):
        rest_tip_radius_px(video, OFF)
    hints = load_feature_hints(clip / "hints.toml", FRAME_SIZE)
    radius = rest_tip_radius_px(video, OFF, FrontEndOptions(features=hints))
    assert radius == pytest.approx(rest_tip_radius_px(video, SENSOR), abs=0.01)
    argv = ["calibrate-sensor", str(video), "--square-side-mm", "5", "--out", "b.toml"]
    assert build_parser().parse_args(argv + ["--features", "h.toml"]).features == "h.toml"
