"""The overlay: annotated frames, the rest check image, the annotated video and its command.

One 6-frame nominal video (seed 911: rest, then tilts of 7.5 and 30 deg) is rendered per module
and tracked once. Tolerances:

- colours read back from the H.264 output: 60 DN per channel (4:4:4 at crf 18
  moves a saturated 7 px dot's centre by a few DN; the scene's nearest colour
  to a marker's is > 150 DN away in some channel);
- where a marker is looked for: the pixel nearest the point (the dot has a
  3 px radius, so that pixel is inside it wherever the point lies in it);
- the model's outline against the renderer's truth: the square 1.2 px, the
  cross 0.3 px. The outline goes through the front end's points, model plus
  rest offsets, and the offsets are the detector's bias at rest: on this
  scene it finds the square's corners ~0.9 px inside the true ones; the
  cross's outline moves by its corners' mean offset, where those biases
  cancel. The fitted pose adds < 0.1 px;
- an outline or arrow line drawn on black is looked for within 1 px of a
  point it should pass (see ``_lit``).
"""

from __future__ import annotations

import json

import av
import cv2
import numpy as np
import pytest

from camwhisker.cli import main
from camwhisker.run.overlay import (
    ARROW_BGR,
    OUTLINE_BGR,
    TRACKED_BGR,
    UNTRACKED_BGR,
    Placement,
    annotate_frame,
    pose_vector,
    rest_check_image,
    status_line,
    write_rest_check,
)
from camwhisker.sensor.file import Sensor, dump_sensor, load_sensor
from camwhisker.sensor.model import N_SQUARE, TIP
from camwhisker.sensor.plate import Pose, feature_pixels
from camwhisker.sim.render.scenarios import make_scenario
from camwhisker.sim.render.video import render_scenario
from camwhisker.vision.tracker import FrameResult, FrontEnd

COLOUR_TOL_DN = 60
SQUARE_TOL_PX = 1.2
CROSS_TOL_PX = 0.3
N_FRAMES = 6
LIT_SHARE = 0.45


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """The rendered video, its sensor and truth, its frames, and the front end's results
    with the pose vector of each frame."""
    d = tmp_path_factory.mktemp("overlay")
    scenario = make_scenario("nominal", N_FRAMES, 911, fps=25.0)
    paths = render_scenario(scenario, Sensor(), d / "nom.avi", 911)
    sensor = load_sensor(paths["sensor"])
    cap = cv2.VideoCapture(str(paths["video"]))
    frames = []
    while (got := cap.read())[0]:
        frames.append(got[1])
    fe = FrontEnd(sensor)
    results, qs, fe_qs = [fe.start(frames[0], 0)], [np.zeros(5)], [fe.q.copy()]
    for i, frame in enumerate(frames[1:], 1):
        results.append(fe.update(frame, i))
        qs.append(pose_vector(results[-1]))
        fe_qs.append(fe.q.copy())
    truth = scenario.track  # the truth file leaves theta empty at phi = 0
    return {"paths": paths, "sensor": sensor, "frames": frames, "results": results, "qs": qs,
            "fe_qs": fe_qs, "model": fe.model, "truth": truth}  # fmt: skip


@pytest.fixture(scope="module")
def annotated(scene, tmp_path_factory):
    """`camwhisker overlay` on the scene: the output's folder and its decoded frames."""
    d = tmp_path_factory.mktemp("overlay_out")
    out = d / "ann.mp4"
    rc = main(["overlay", str(scene["paths"]["video"]), "--sensor", str(scene["paths"]["sensor"]),
               "--out", str(out), "--quiet"])  # fmt: skip
    assert rc == 0
    cap = cv2.VideoCapture(str(out))
    frames = []
    while (got := cap.read())[0]:
        frames.append(got[1])
    return d, frames


def _near(image, uv, colour, radius_px=0):
    """Whether a pixel within ``radius_px`` (Chebyshev) of the pixel nearest ``uv`` has
    ``colour`` to within COLOUR_TOL_DN in every channel."""
    u, v = np.rint(uv).astype(int)
    r = radius_px
    patch = image[v - r : v + r + 1, u - r : u + r + 1].astype(int)
    return bool((np.abs(patch - np.array(colour)).max(axis=-1) <= COLOUR_TOL_DN).any())


def _lit(image, uv, colour, radius_px=1):
    """Whether a line of ``colour`` drawn on black passes within ``radius_px`` of the
    pixel nearest ``uv``: some pixel there holds at least LIT_SHARE of the colour
    (an anti-aliased line lights the pixel its centre crosses by at least half)."""
    u, v = np.rint(uv).astype(int)
    r = radius_px
    patch = image[v - r : v + r + 1, u - r : u + r + 1].astype(float)
    c = np.array(colour, float)
    return bool(((patch @ c) / (c @ c)).max() >= LIT_SHARE)


def test_output_has_every_frame_at_the_input_size(scene, annotated):
    d, frames = annotated
    assert len(frames) == len(scene["frames"]) == N_FRAMES
    assert {f.shape for f in frames} == {scene["frames"][0].shape} == {(720, 1280, 3)}
    meta = json.loads((d / "ann.overlay.json").read_text())
    assert meta["camwhisker_version"] and meta["made_by"] == "camwhisker.run.overlay.annotate_video"
    assert meta["frames"] == N_FRAMES and meta["frames_ok"] == N_FRAMES
    assert meta["arrow_scale"] == 10.0 and meta["rest_frame"] == 0
    assert meta["sensor_file"] == str(scene["paths"]["sensor"])
    assert meta["options"]["mode"] == "model"
    assert (d / "ann.rest.png").is_file()
    with av.open(str(d / "ann.mp4")) as container:
        assert container.streams.video[0].codec_context.name == "h264"
    assert not list(d.glob(".ann*"))  # no temporary left behind


def test_tracked_points_carry_their_marker(scene, annotated):
    _, frames = annotated
    n_checked = 0
    for image, result in zip(frames, scene["results"], strict=True):
        for k, uv in enumerate(result.points_uv):
            if np.isfinite(uv).all() and k != TIP:
                assert _near(image, uv, TRACKED_BGR), (result.frame, k)
                n_checked += 1
    assert n_checked >= 8 * N_FRAMES  # most corners are tracked on every frame


def test_input_frame_is_left_as_it_was(scene):
    frame = scene["frames"][3]
    before = frame.copy()
    placement = Placement.from_rest(scene["model"], scene["results"][0])
    out = annotate_frame(frame, scene["results"][3], placement, scene["qs"][3])
    assert np.array_equal(frame, before)
    assert out is not frame and out.shape == frame.shape
    assert (out != frame).any(axis=-1).sum() > 500  # markers, outline, arrows, text


@pytest.mark.parametrize("index", [0, 3, 4])
def test_outline_meets_the_true_corners(scene, index):
    q = scene["qs"][index]
    assert q is not None
    placement = Placement.from_rest(scene["model"], scene["results"][0])
    truth = feature_pixels(scene["truth"].pose(index), scene["sensor"])
    outlines = placement.outlines(q)
    err_sq = np.hypot(*(outlines["square"] - truth["square_corners"]).T)
    err_cr = np.hypot(*(outlines["cross"] - truth["cross_outline"]).T)
    assert err_sq.max() < SQUARE_TOL_PX and err_cr.max() < CROSS_TOL_PX
    # ... and the drawn lines pass through every vertex.
    blank = np.zeros_like(scene["frames"][index])
    drawn = annotate_frame(blank, scene["results"][index], placement, q, layers=("outline",))
    for uv in np.concatenate(list(outlines.values())):
        assert _lit(drawn, uv, OUTLINE_BGR), uv


def test_untracked_point_is_crossed_where_expected_and_arrows_scale(scene):
    rest = scene["results"][0]
    placement = Placement.from_rest(scene["model"], rest)
    uv = rest.points_uv.copy()
    uv[0] = np.nan  # square_tl not tracked
    uv[N_SQUARE] += [1.0, 0.0]  # a cross corner moved 1 px right
    moved = FrameResult(frame=1, dz_mm=0.0, phi_deg=0.0, theta_deg=np.nan, ok=True,
                        model=(0.0, 0.0, np.nan), paper=(0.0, 0.0, np.nan), points_uv=uv,
                        quality=np.ones(TIP + 1))  # fmt: skip
    blank = np.zeros_like(scene["frames"][0])
    image = annotate_frame(blank, moved, placement, np.zeros(5), layers=("points",))
    assert _near(image, rest.points_uv[0], UNTRACKED_BGR)
    assert not _near(image, rest.points_uv[0], TRACKED_BGR, radius_px=2)
    for scale in (10.0, 20.0):
        image = annotate_frame(blank, moved, placement, None, scale, layers=("arrows",))
        tip_uv = rest.points_uv[N_SQUARE] + [scale - 2.0, 0.0]
        beyond_uv = rest.points_uv[N_SQUARE] + [scale + 3.0, 0.0]
        assert _lit(image, tip_uv, ARROW_BGR, radius_px=0)
        assert not _lit(image, beyond_uv, ARROW_BGR, radius_px=1)


def test_result_carries_the_fitted_pose(scene):
    """FrameResult.q is the front end's fit: zeros at rest, its pose after each update
    (theta unmasked, so small tilts keep their direction), NaN with no fit."""
    assert np.array_equal(scene["results"][0].q, np.zeros(5))
    for result, fe_q in zip(scene["results"], scene["fe_qs"], strict=True):
        assert result.ok
        np.testing.assert_array_equal(result.q, fe_q)
    assert np.isnan(FrameResult.untrusted(7, "lost").q).all()


def test_pose_vector_and_status_line(scene):
    result, q = scene["results"][3], scene["qs"][3]
    assert q[0] == pytest.approx(result.model[0], abs=1e-12)
    assert np.degrees(np.hypot(q[1], q[2])) == pytest.approx(result.model[1], abs=1e-9)
    # Without the front end's pose, from the result's own angles (theta is known here).
    assert result.model[1] > 0.6
    np.testing.assert_allclose(pose_vector(result), q, atol=1e-9)
    assert pose_vector(FrameResult.untrusted(7, "lost")) is None
    line = status_line(result)
    assert line.startswith("frame 3  dz ") and line.endswith(" ok")
    assert f"phi {result.phi_deg:.2f} deg" in line
    lost = status_line(FrameResult.untrusted(7, "tip: not found"))
    assert lost.endswith("theta - deg  tip: not found")


def test_rest_check_image_is_written(scene, tmp_path):
    frame, rest = scene["frames"][0], scene["results"][0]
    path = write_rest_check(tmp_path / "r.rest.png", frame, rest, scene["model"])
    image = cv2.imread(str(path))
    assert image.shape == frame.shape
    assert np.array_equal(image, rest_check_image(frame, rest, scene["model"]))  # PNG: lossless
    for uv in rest.points_uv[:TIP]:
        assert _near(image, uv, TRACKED_BGR)
    truth = feature_pixels(Pose(0.0, 0.0, 0.0), scene["sensor"])["square_corners"]
    assert np.hypot(*(rest.points_uv[:N_SQUARE] - truth).T).max() < SQUARE_TOL_PX


def test_bad_inputs_get_the_one_error_style(scene, tmp_path, capsys):
    out = tmp_path / "o.mp4"
    assert main(["overlay", str(tmp_path / "none.mp4"), "--out", str(out)]) == 2
    assert "camwhisker overlay: error:" in capsys.readouterr().err
    junk = tmp_path / "junk.mp4"
    junk.write_text("not a video")
    assert main(["overlay", str(junk), "--out", str(out)]) == 2
    assert "not a video" in capsys.readouterr().err
    small = tmp_path / "small.toml"
    small_sensor = scene["sensor"].replace(
        camera={"width_px": 640, "height_px": 480, "cx_px": 319.5, "cy_px": 239.5}
    )
    small.write_text(dump_sensor(small_sensor))
    rc = main(["overlay", str(scene["paths"]["video"]), "--sensor", str(small), "--out", str(out),
               "--quiet"])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err
    assert f"{scene['paths']['video']}: frames are 1280x720 px but {small} is for 640x480" in err
    assert list(tmp_path.glob("o*")) == [] and list(tmp_path.glob(".o*")) == []
    assert main(["overlay", str(scene["paths"]["video"]), "--out", str(tmp_path / "o.mkv")]) == 2
    assert main(["overlay", str(scene["paths"]["video"]), "--out", str(out),
                 "--rest-frame", "9", "--quiet"]) == 2  # fmt: skip
    assert "no frame 9" in capsys.readouterr().err
    assert list(tmp_path.glob("o*")) == []
