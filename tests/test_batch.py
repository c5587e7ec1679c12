"""The batch command: video -> signal table + sidecar + rest check image, and its bad inputs.

One 6-frame nominal video (seed 911) is rendered per module. Accuracy is the
business of test_vision_accuracy; here the tolerance on phi (0.1 deg) only
checks that the table carries the front end's numbers, in the right rows.
"""

from __future__ import annotations

import csv
import json

import cv2
import numpy as np
import pytest

from camwhisker.cli import main
from camwhisker.io.sources import open_source
from camwhisker.run.overlay import rest_check_image
from camwhisker.sensor.file import load_sensor
from camwhisker.sensor.model import PlateModel
from camwhisker.sim.render.scenarios import PoseTrack, make_scenario
from camwhisker.sim.render.video import render_scenario
from camwhisker.vision.stream import stream

REQUIRED = ["frame", "t_s", "dz_mm", "phi_deg", "theta_deg", "ok"]


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    d = tmp_path_factory.mktemp("batch")
    sc = make_scenario("nominal", 6, 911, fps=25.0)
    from camwhisker.sensor.file import Sensor

    paths = render_scenario(sc, Sensor(), d / "nom.avi", 911)
    return paths


def _read(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_batch_writes_the_signal_table(video, tmp_path, capsys):
    out = tmp_path / "sig.csv"
    rc = main(["batch", str(video["video"]), "--sensor", str(video["sensor"]), "--out", str(out)])
    assert rc == 0
    rows = _read(out)
    assert list(rows[0])[:6] == REQUIRED
    truth = PoseTrack.read_csv(video["truth"])
    assert [int(r["frame"]) for r in rows] == list(range(6))
    np.testing.assert_allclose([float(r["t_s"]) for r in rows], np.arange(6) / 25.0, atol=1e-6)
    for r, phi in zip(rows, truth.phi_deg, strict=True):
        assert r["ok"] == "1"
        assert abs(float(r["phi_deg"]) - phi) < 0.1
        assert (r["theta_deg"] == "") == (phi < 0.6)
    meta = json.loads((tmp_path / "sig.json").read_text())
    assert meta["camwhisker_version"]
    assert meta["options"]["mode"] == "model"
    assert meta["sensor"]["plate"]["h_r_mm"] == 7.5
    assert meta["frames"] == 6 and meta["frames_ok"] == 6 and meta["problems"] == []
    assert meta["time_source"] == "container"
    assert "6 frames, 6 ok" in capsys.readouterr().out


def test_batch_paper_mode(video, tmp_path):
    out = tmp_path / "paper.csv"
    rc = main(["batch", str(video["video"]), "--sensor", str(video["sensor"]), "--out", str(out),
               "--mode", "paper"])  # fmt: skip
    assert rc == 0
    rows = _read(out)
    truth = PoseTrack.read_csv(video["truth"])
    big = truth.phi_deg > 10
    assert big.any()
    phi = np.array([float(r["phi_deg"]) for r in rows])
    ratio = np.tan(np.radians(phi[big])) / np.tan(np.radians(truth.phi_deg[big]))
    assert np.all((ratio > 0.4) & (ratio < 0.6))  # eq. (6)'s half-angle reading
    assert json.loads((tmp_path / "paper.json").read_text())["options"]["mode"] == "paper"


def test_truncated_video_keeps_the_readable_part(video, tmp_path, capsys):
    data = video["video"].read_bytes()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    out = tmp_path / "cut.csv"
    rc = main(["batch", str(cut), "--sensor", str(video["sensor"]), "--out", str(out)])
    assert rc == 1  # finished, something failed (README, Exit status)
    rows = _read(out)
    assert 1 <= len(rows) < 6
    # The last frame the decoder returns may be half old data: flagged, not trusted.
    assert all(r["ok"] == "1" for r in rows[:-1])
    assert rows[-1]["ok"] == "1" or rows[-1]["phi_deg"] == ""
    assert "truncated" in capsys.readouterr().err
    meta = json.loads((tmp_path / "cut.json").read_text())
    assert meta["frames"] == len(rows) and "truncated" in meta["problems"][0]


def test_missing_file_is_a_clear_error(tmp_path, capsys):
    out = tmp_path / "x.csv"
    assert main(["batch", str(tmp_path / "nope.avi"), "--out", str(out)]) == 2
    assert "no such file" in capsys.readouterr().err
    assert not out.exists()


def test_non_video_is_a_clear_error(tmp_path, capsys):
    bad = tmp_path / "notes.avi"
    bad.write_text("this is not a video\n")
    out = tmp_path / "x.csv"
    assert main(["batch", str(bad), "--out", str(out)]) == 2
    assert "not a video" in capsys.readouterr().err
    assert not out.exists()


def test_features_not_found_is_a_clear_error(tmp_path, capsys):
    folder = tmp_path / "blank"
    folder.mkdir()
    for i in range(2):
        cv2.imwrite(str(folder / f"{i:03d}.png"), np.full((720, 1280, 3), 215, np.uint8))
    out = tmp_path / "x.csv"
    assert main(["batch", str(folder), "--out", str(out), "--fps", "10"]) == 2
    err = capsys.readouterr().err
    assert "features not found" in err and "magnifier tip" in err and "square corners" in err
    assert not out.exists() and not list(tmp_path.glob(".x.*"))


def test_image_folder_uses_index_over_fps(video, tmp_path):
    cap = cv2.VideoCapture(str(video["video"]))
    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(3):
        ok, img = cap.read()
        assert ok
        cv2.imwrite(str(folder / f"f{i:04d}.png"), img)
    cap.release()
    out = tmp_path / "f.csv"
    rc = main(["batch", str(folder), "--sensor", str(video["sensor"]), "--out", str(out),
               "--fps", "8", "--quiet"])  # fmt: skip
    assert rc == 0
    rows = _read(out)
    assert [float(r["t_s"]) for r in rows] == [0.0, 0.125, 0.25]
    assert json.loads((tmp_path / "f.json").read_text())["time_source"] == "index / fps"


def test_rest_frame_option_leaves_earlier_rows_untrusted(video, tmp_path):
    out = tmp_path / "r.csv"
    rc = main(["batch", str(video["video"]), "--sensor", str(video["sensor"]), "--out", str(out),
               "--rest-frame", "1", "--quiet"])  # fmt: skip
    assert rc == 0
    rows = _read(out)
    assert rows[0]["ok"] == "0" and rows[0]["phi_deg"] == "" and rows[0]["dz_mm"] == ""
    # The rest frame is measured against the reference averaged over the frames at rest
    # from it on, so it reads its own noise (~0.005 deg here) instead of exactly 0.
    assert rows[1]["ok"] == "1" and abs(float(rows[1]["phi_deg"])) < 0.02


def test_tracker_knobs_from_the_command_line(video, tmp_path, capsys):
    out = tmp_path / "k.csv"
    rc = main(["batch", str(video["video"]), "--sensor", str(video["sensor"]), "--out", str(out),
               "--lk-half-px", "10", "--quiet"])  # fmt: skip
    assert rc == 0
    options = json.loads((tmp_path / "k.json").read_text())["options"]
    assert options["lk_half_px"] == 10
    truth = PoseTrack.read_csv(video["truth"])
    rows = _read(out)
    assert all(r["ok"] == "1" for r in rows)
    # a smaller window tracks this clip too, if less closely than the default
    assert max(abs(float(r["phi_deg"]) - p) for r, p in zip(rows, truth.phi_deg, strict=True)) < 0.1
    assert main(["batch", str(video["video"]), "--out", str(tmp_path / "b.csv"),
                 "--lk-half-px", "2"]) == 2  # fmt: skip
    assert "lk_half_px" in capsys.readouterr().err and not (tmp_path / "b.csv").exists()


def test_negative_rest_frame_is_refused(video, tmp_path, capsys):
    out = tmp_path / "n.csv"
    assert main(["batch", str(video["video"]), "--out", str(out), "--rest-frame", "-1"]) == 2
    assert "--rest-frame" in capsys.readouterr().err and not out.exists()


def _frame(video, index):
    """Frame ``index`` as batch decodes it."""
    return next(f.image for f in open_source(video) if f.index == index)


def test_batch_writes_the_rest_check_image(video, tmp_path):
    """OUT.rest.png beside the table: the rest frame (here frame 1) with its features
    named, at the frame's size; the sidecar names it."""
    out = tmp_path / "sig.csv"
    rc = main(["batch", str(video["video"]), "--sensor", str(video["sensor"]), "--out", str(out),
               "--rest-frame", "1", "--quiet"])  # fmt: skip
    assert rc == 0
    image = cv2.imread(str(tmp_path / "sig.rest.png"))
    frame = _frame(video["video"], 1)
    assert image is not None and image.shape == frame.shape == (720, 1280, 3)
    assert json.loads((tmp_path / "sig.json").read_text())["rest_check"] == "sig.rest.png"
    sensor = load_sensor(video["sensor"])
    rest = next(r for _, r in stream(open_source(video["video"]), sensor, rest_index=1) if r.ok)
    assert rest.frame == 1
    assert np.array_equal(image, rest_check_image(frame, rest, PlateModel(sensor)))  # PNG: lossless
