"""Cameras (listing against a fake sysfs tree), the settings profile, the command line,
clean shutdown on SIGTERM / Ctrl-C, the signal-table format, and the latency bench."""

from __future__ import annotations

import csv
import dataclasses
import json
import logging
import math
import os
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from camwhisker.bench.live import _jpegs, bench_frames
from camwhisker.bench.live import main as bench_main
from camwhisker.cli import main
from camwhisker.io.signals import SignalWriter, write_signals
from camwhisker.io.sources import VideoSource, read_timestamps, timestamps_path
from camwhisker.live.cameras import (
    C310_PROFILE,
    NO_CAMERA_MESSAGE,
    V4L2_CAP_DEVICE_CAPS,
    V4L2_CAP_META_CAPTURE,
    V4L2_CAP_VIDEO_CAPTURE,
    apply_profile,
    list_cameras,
    parse_querycap,
    resolve_camera,
)
from camwhisker.live.capture import READ_CLOCK, CameraCapture
from camwhisker.live.grabber import Grabber
from camwhisker.live.loop import LiveConfig, run_live
from camwhisker.live.record import MjpgRoundTrip, decode_only
from camwhisker.sensor.file import load_sensor
from camwhisker.vision.tracker import FrameResult

# Plays video at camera rate or times a live loop: run alone (README's test command).
pytestmark = pytest.mark.timing

SAMPLES = Path(__file__).resolve().parents[1] / "sample_frames"
CLIP = SAMPLES / "nominal.mp4"
SENSOR = SAMPLES / "nominal.sensor.toml"
C310_ID = "usb-046d_081b_3F2B1C10-video-index"


def _fake_v4l(root: Path) -> tuple[Path, Path]:
    """A C310 (capture node video0 + metadata node video1) and a by-id-less camera video2."""
    sysfs, dev = root / "sys", root / "dev"
    for node, name, index in (("video0", "UVC Camera (046d:081b)", 0),
                              ("video1", "UVC Camera (046d:081b)", 1),
                              ("video2", "Integrated Camera", 0)):  # fmt: skip
        (sysfs / node).mkdir(parents=True)
        (sysfs / node / "name").write_text(name + "\n")
        (sysfs / node / "index").write_text(f"{index}\n")
    (sysfs / "vbi0").mkdir()  # not a video node
    by_id = dev / "v4l" / "by-id"
    by_id.mkdir(parents=True)
    for i in (0, 1):
        (dev / f"video{i}").write_text("")  # a plain file: the driver cannot be asked
        os.symlink(f"../../video{i}", by_id / f"{C310_ID}{i}")
    return sysfs, dev


def test_list_cameras_skips_metadata_nodes(tmp_path):
    sysfs, dev = _fake_v4l(tmp_path)
    cams = list_cameras(sysfs, dev)
    assert [Path(c.node).name for c in cams] == ["video0", "video2"]
    assert cams[0].name == "UVC Camera (046d:081b)" and cams[0].how == "sysfs index"
    assert [Path(p).name for p in cams[0].by_id] == [f"{C310_ID}0"] and cams[1].by_id == ()
    every = list_cameras(sysfs, dev, include_metadata=True)
    assert [c.captures for c in every] == [True, False, True]


def test_list_cameras_command(tmp_path, capsys):
    sysfs, dev = _fake_v4l(tmp_path)
    assert main(["list-cameras", "--sysfs", str(sysfs), "--dev", str(dev)]) == 0
    out = capsys.readouterr().out
    assert f"{C310_ID}0" in out and f"{C310_ID}1" not in out and "video1" not in out
    assert "Integrated Camera" in out and "no /dev/v4l/by-id link" in out
    empty = tmp_path / "none"
    empty.mkdir()
    assert main(["list-cameras", "--sysfs", str(empty), "--dev", str(empty)]) == 1
    assert capsys.readouterr().out.strip() == NO_CAMERA_MESSAGE
    assert list_cameras(tmp_path / "no-such-folder", dev) == []


def test_resolve_camera_names(tmp_path):
    _, dev = _fake_v4l(tmp_path)
    assert resolve_camera("2") == 2 and resolve_camera(0) == 0
    node = str((dev / "video0").resolve())
    assert resolve_camera(f"{C310_ID}0", dev) == node  # bare stable name
    assert resolve_camera(str(dev / "v4l" / "by-id" / f"{C310_ID}0"), dev) == node
    with pytest.raises(FileNotFoundError, match="list-cameras"):
        resolve_camera("usb-nothing-video-index0", dev)


def test_parse_querycap():
    def cap(caps, device_caps):
        return struct.pack("16s32s32sIII12x", b"uvcvideo", b"C310", b"usb-1", 1, caps, device_caps)

    both = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_META_CAPTURE | V4L2_CAP_DEVICE_CAPS
    assert parse_querycap(cap(both, V4L2_CAP_VIDEO_CAPTURE)) == ("uvcvideo", "C310", True)
    assert parse_querycap(cap(both, V4L2_CAP_META_CAPTURE))[2] is False  # metadata node
    assert parse_querycap(cap(V4L2_CAP_VIDEO_CAPTURE, 0))[2] is True  # no device caps


def test_profile_that_does_not_take_warns_requested_vs_applied(caplog):
    cap = cv2.VideoCapture(str(CLIP))  # a file ignores every camera control
    with caplog.at_level(logging.WARNING, logger="camwhisker.live.cameras"):
        s = apply_profile(cap, C310_PROFILE)
    cap.release()
    assert "auto_wb: requested 0.0, applied -1.0" in s.mismatches
    assert any(m.startswith("fourcc: requested MJPG, applied") for m in s.mismatches)
    assert "width_px" not in " ".join(s.mismatches)  # the file is 1280 wide: that one holds
    assert s.applied["width_px"] == 1280.0 and s.requested["fps"] == 30.0
    (msg,) = [m for m in caplog.messages if "requested vs applied" in m]
    assert "auto_wb: requested 0.0, applied -1.0" in msg


class ObedientCapture:
    """A capture whose set() always takes: no warning may come."""

    def __init__(self):
        self.props = {}

    def set(self, prop, value):
        self.props[prop] = value
        return True

    def get(self, prop):
        return self.props.get(prop, -1.0)


def test_profile_that_takes_gives_no_warning(caplog):
    with caplog.at_level(logging.WARNING, logger="camwhisker.live.cameras"):
        s = apply_profile(ObedientCapture(), C310_PROFILE)
    assert s.mismatches == [] and s.applied["fourcc"] == "MJPG"
    assert not caplog.messages


def test_camera_path_records_settings_in_the_sidecar(tmp_path):
    """The whole camera path (profile, read-back, warm-up) on a capture that opens a file."""
    # frames 0-8 of the clip are at rest: 3 warm-up frames leave rest frames to start on
    profile = dataclasses.replace(C310_PROFILE, warmup_frames=3)
    cam = CameraCapture("test-camera", profile, opener=lambda _t: cv2.VideoCapture(str(CLIP)))
    out = tmp_path / "cam.csv"
    rep = run_live(cam, load_sensor(SENSOR), out, LiveConfig(mode="every", max_frames=5,
                                                            controls=False))  # fmt: skip
    meta = json.loads(out.with_suffix(".json").read_text())
    settings = meta["input"]["settings"]
    assert settings["warmup_discarded"] == 3
    assert "auto_wb: requested 0.0, applied -1.0" in settings["mismatches"]
    assert settings["requested"]["fourcc"] == "MJPG" and meta["input"]["kind"] == "camera"
    assert rep.rows == 5 and rep.rows_ok == 5
    # A file's CAP_PROP_POS_MSEC is its position, not a monotonic time: the read's time.
    assert rep.grabber["clock"] == READ_CLOCK and meta["grabber"]["clock"] == READ_CLOCK
    measured = rep.grabber["fps_measured"]  # a file decodes faster than the 30 fps it states
    if abs(measured - 30.0) > 3.0:
        assert f"the camera reports 30 fps; measured {measured:.1f}" in rep.problems


class GarbageCapture:
    """Two reads of bytes that look like a camera's raw JPEG but are not, then the end."""

    def __init__(self):
        self.n = 0

    @property
    def ended(self):
        return self.n > 2

    def read(self):
        self.n += 1
        if self.n > 2:
            return False, None
        return True, np.frombuffer(b"\xff\xd8 not a jpeg", np.uint8)


@pytest.mark.parametrize("prepare", [MjpgRoundTrip(), decode_only], ids=["record", "raw"])
def test_a_frame_that_does_not_decode_is_a_gap(prepare):
    g = Grabber(GarbageCapture(), "every", prepare, backoff_s=0.001).start()
    items = []
    while (item := g.get(5.0)) is not None:
        items.append(item)
    g.stop()
    assert [i.image for i in items] == [None, None] and [i.seq for i in items] == [0, 1]
    assert all(i.error.startswith("frame did not decode") for i in items)
    assert g.stats.failed_reads == 2 and g.stats.ended and not g.stats.lost


def test_signal_row_is_batch_format(tmp_path):
    nan3 = (math.nan,) * 3
    results = [
        FrameResult(frame=0, dz_mm=0.0, phi_deg=0.0, theta_deg=math.nan, ok=True,
                    model=(0.0, 0.0, math.nan), paper=nan3, sx_mm=0.0, sy_mm=0.0,
                    phi_sigma_deg=0.0, rms_px=0.0, n_corners=12),
        FrameResult(frame=1, dz_mm=0.123456789, phi_deg=12.3456789, theta_deg=-170.12345,
                    ok=True, model=nan3, paper=nan3, sx_mm=0.01, sy_mm=-0.02,
                    phi_sigma_deg=0.003, rms_px=0.25, n_corners=9),
        FrameResult(frame=2, dz_mm=math.nan, phi_deg=math.nan, theta_deg=math.nan, ok=False,
                    model=nan3, paper=nan3, reason="tip: lost, x"),
        FrameResult(frame=3, dz_mm=0.5, phi_deg=1.0, theta_deg=2.0, ok=False, model=nan3,
                    paper=nan3, rms_px=0.7, reason="poor fit"),
    ]  # fmt: skip
    times = [0.0, 0.0333333333, 1e-7, math.nan]
    write_signals(tmp_path / "batch.csv", zip(times, results, strict=True))
    w = SignalWriter(tmp_path / "live.csv", flush=True)
    for t, r in zip(times, results, strict=True):
        w.write(t, r)
    w.close()
    assert (tmp_path / "live.csv").read_bytes() == (tmp_path / "batch.csv").read_bytes()
    assert (w.rows, w.rows_ok) == (4, 2)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_closes_every_file(tmp_path, sig):
    out, avi = tmp_path / "live.csv", tmp_path / "s.avi"
    cmd = [sys.executable, "-m", "camwhisker.cli", "live", str(CLIP), "--playback-fps", "30",
           "--loop", "--out", str(out), "--record", str(avi), "--sensor", str(SENSOR),
           "--no-keys"]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60.0  # start-up (imports) on a loaded machine
    try:
        while time.monotonic() < deadline:
            if out.exists() and len(out.read_text().splitlines()) > 8:
                break
            if proc.poll() is not None:
                break
            time.sleep(0.1)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert f"stopped by {signal.Signals(sig).name}" in err and "p99" in err
    with open(out, newline="") as fh:
        rows = list(csv.reader(fh))
    assert len(rows) > 9 and all(len(r) == 12 for r in rows)  # no half-written row
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["stopped_by"] == signal.Signals(sig).name
    assert meta["frames"] == len(rows) - 1 == meta["recording"]["frames"]
    stamps = read_timestamps(timestamps_path(avi))
    assert len(stamps) == len(rows) - 1
    assert len(list(VideoSource(avi))) == len(stamps)  # the AVI is finalised and whole
    again = tmp_path / "again.csv"
    assert main(["replay", str(avi), "--out", str(again), "--sensor", str(SENSOR)]) == 0
    assert again.read_bytes() == out.read_bytes()


def test_latency_bench_on_the_mjpg_sample(capsys):
    jpegs = _jpegs(SAMPLES / "nominal_mjpg.avi")
    assert len(jpegs) == 12
    b = bench_frames(jpegs, load_sensor(SAMPLES / "nominal_mjpg.sensor.toml"))
    p = b.processing
    assert b.frames == p["n"] == 11 and b.threads == 1
    assert 0 < p["p50_ms"] <= p["p99_ms"] <= p["max_ms"] and b.rest_ms > 0
    # CPU time of the processing thread cannot exceed its wall-clock (one thread)
    assert b.cpu["n"] == 11 and 0 < b.cpu["mean_ms"] <= 1.05 * p["mean_ms"]
    assert b.decode["n"] == 12 and b.ok_share == 1.0
    # each frame's decode plus processing is at least its processing: so are the quantiles
    w = b.with_decode
    assert w["n"] == 11 and w["p50_ms"] >= p["p50_ms"] and w["p99_ms"] >= p["p99_ms"]
    assert math.isnan(b.phi_rmse_deg)  # no truth given
    assert bench_main(["--video", str(SAMPLES / "nominal_mjpg.avi"),
                       "--sensor", str(SAMPLES / "nominal_mjpg.sensor.toml")]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert "p99" in out and "11 frames of 1280x720, 1 OpenCV thread" in out
    assert "100% rows ok, phi RMSE 0.0" in out  # the sample's truth is beside it
    np.testing.assert_array_less(0, [p["mean_ms"], b.decode["p50_ms"]])


def test_latency_bench_least_over_passes(capsys):
    """Each frame's least CPU time over passes is at most its first pass's; the rows repeat."""
    jpegs = _jpegs(SAMPLES / "nominal_mjpg.avi")
    sensor = load_sensor(SAMPLES / "nominal_mjpg.sensor.toml")
    b = bench_frames(jpegs, sensor, passes=3)
    assert b.passes == 3 and b.cpu_least["n"] == b.cpu["n"] == 11
    assert 0 < b.cpu_least["p50_ms"] <= b.cpu["max_ms"]
    assert b.cpu_least["mean_ms"] <= b.cpu["mean_ms"] and b.cpu_least["max_ms"] <= b.cpu["max_ms"]
    assert bench_frames(jpegs, sensor).cpu_least is None
    with pytest.raises(ValueError, match="passes"):
        bench_frames(jpegs, sensor, passes=0)
    assert bench_main(["--video", str(SAMPLES / "nominal_mjpg.avi"), "--passes", "2",
                       "--sensor", str(SAMPLES / "nominal_mjpg.sensor.toml")]) == 0  # fmt: skip
    assert "least CPU time over 2 passes: p50" in capsys.readouterr().out


def test_a_missing_camera_is_one_line_of_error(tmp_path):
    # No /dev/video7 on a test machine (checked: else the test would open a real camera).
    assert not Path("/dev/video7").exists()
    env = {k: v for k, v in os.environ.items() if k != "OPENCV_LOG_LEVEL"}
    done = subprocess.run([sys.executable, "-m", "camwhisker.cli", "live", "7", "--sensor",
                           str(Path(__file__).resolve().parents[1] / "sample_frames" /
                               "nominal.sensor.toml"), "--out", str(tmp_path / "x.csv")],
                          capture_output=True, text=True, env=env, timeout=120)  # fmt: skip
    # camwhisker's error alone: OpenCV's own "[ WARN ...] can't open camera" lines are quiet.
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == ["camwhisker live: error: camera 7: cannot open 7"]
    assert not (tmp_path / "x.csv").exists()
