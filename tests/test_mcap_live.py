"""live and replay --mcap (docs/robots.md): the rows streamed as ROS 2 messages that
decode to the signal table's values, the frames' JPEG bytes as the recording holds them,
the wrench and the contact points; a stopped session leaves a whole bag.

Files are played as fast as they decode (1000 fps, keep every): nothing here depends on
timing, so the file runs with the others.
"""

from __future__ import annotations

import functools
import json
import math
import subprocess
import sys
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from scipy.spatial.transform import Rotation

import camwhisker.live.loop
from camwhisker.cli import main
from camwhisker.files.tables import read_columns
from camwhisker.io.bag import BagError, BagStream, BagThread
from camwhisker.io.sources import VideoSource
from camwhisker.live.base import write_pose_log
from camwhisker.live.loop import LiveConfig, LiveSession
from camwhisker.live.playback import PlaybackSource
from camwhisker.live.record import MjpgRoundTrip, SessionRecorder
from camwhisker.sensor.file import load_sensor

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_frames"
CLIP = SAMPLES / "nominal_mjpg.avi"  # 12 MJPG frames, 1280 x 720
CLIP_SENSOR = SAMPLES / "nominal_mjpg.sensor.toml"
SPACE = SAMPLES / "space"
TEXT = ("note", "doubt")  # text columns: no field


def _springs(tmp_path: Path) -> Path:
    path = tmp_path / "springs.toml"
    path.write_text("[stiffness]\nk_z_n_per_mm = 0.05\nk_phi_nmm_per_rad = 20.0\n")
    return path


def _bag(path: Path) -> tuple[dict, dict[str, list]]:
    """The bag's message counts per topic (from its summary: a bag that was finished) and
    each topic's (log time, decoded message) in log-time order."""
    out: dict[str, list] = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None  # closed, not cut off
        counts = {summary.channels[c].topic: n
                  for c, n in summary.statistics.channel_message_counts.items()}  # fmt: skip
        for _, channel, message, msg in reader.iter_decoded_messages():
            out.setdefault(channel.topic, []).append((message.log_time, msg))
    return counts, out


def _table(path: Path) -> dict:
    header = path.read_text().splitlines()[0].split(",")
    return read_columns(path, tuple(c for c in header if c not in TEXT))


def _ns(stamp) -> int:
    return stamp.sec * 10**9 + stamp.nanosec


def _raw_frames(video: Path) -> list[bytes]:
    """Each frame's bytes as the file stores them, read by OpenCV without decoding
    (CAP_PROP_FORMAT -1), not by the PyAV demuxer the package uses."""
    cap = cv2.VideoCapture(str(video), cv2.CAP_FFMPEG)
    assert cap.set(cv2.CAP_PROP_FORMAT, -1)
    out = []
    while True:
        ok, raw = cap.read()
        if not ok:
            break
        out.append(raw.tobytes())
    cap.release()
    return out


def _check_signals(signals: list, table: dict) -> None:
    """One message per row: the stamp t_s to the nanosecond, every field the table's."""
    n = table["t_s"].size
    assert len(signals) == n
    for i, (log_ns, msg) in enumerate(signals):
        # Exact: integer nanoseconds of the table's 6 decimals.
        assert _ns(msg.header.stamp) == log_ns == round(table["t_s"][i] * 1e9)
        assert msg.header.frame_id == "whisker"
        assert msg.frame == int(table["frame"][i]) and msg.ok == (table["ok"][i] == 1)
        for c, values in table.items():
            if c not in ("frame", "ok", "t_s"):
                # Exact, NaN to NaN: the message holds the row's printed cells.
                np.testing.assert_array_equal(getattr(msg, c.lower()), values[i], err_msg=c)


def _check_wrench(wrench: list, signals: list, table: dict) -> int:
    """force.z is -fz_mN / 1000 of the row (exactly: the same division of the same value),
    a message for each row with both forces; returns how many."""
    have = np.flatnonzero(np.isfinite(table["fz_mN"]) & np.isfinite(table["mb_Nmm"]))
    assert len(wrench) == have.size
    for (log_ns, msg), i in zip(wrench, have, strict=True):
        assert log_ns == signals[i][0]
        f = msg.wrench.force
        assert (f.x, f.y, f.z) == (0.0, 0.0, -table["fz_mN"][i] / 1000.0)
    return int(have.size)


def test_live_stopped_early_leaves_a_whole_bag_with_the_recordings_bytes(tmp_path, capsys):
    out, bag, avi = tmp_path / "L.csv", tmp_path / "L.mcap", tmp_path / "S.avi"
    bag.write_bytes(b"an older file, replaced whole")
    rc = main(["live", str(CLIP), "--sensor", str(CLIP_SENSOR), "--out", str(out), "--mcap",
               str(bag), "--record", str(avi), "--springs", str(_springs(tmp_path)),
               "--playback-fps", "1000", "--keep", "every", "--frames", "8", "--no-keys"])
    assert rc == 0, capsys.readouterr().err
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["stopped_by"] == "max_frames"  # 8 of the clip's 12 frames
    assert meta["mcap"] == {"file": str(bag), "rows": 8, "images": 8, "dropped": 0}
    counts, topics = _bag(bag)
    assert counts == {"/whisker/signals": 8, "/whisker/wrench": 8, "/whisker/image": 8}
    table = _table(out)
    _check_signals(topics["/whisker/signals"], table)
    assert _check_wrench(topics["/whisker/wrench"], topics["/whisker/signals"], table) == 8
    # The images: the recording's JPEG bytes, frame for frame, stamped as their rows.
    recorded = _raw_frames(avi)
    assert len(recorded) == 8
    images = topics["/whisker/image"]
    for (log_ns, msg), data, (row_ns, _) in zip(images, recorded, topics["/whisker/signals"],
                                                strict=True):  # fmt: skip
        assert msg.format == "jpeg" and bytes(msg.data) == data and log_ns == row_ns
    assert not [p.name for p in tmp_path.iterdir() if ".tmp" in p.name]  # no temporary left


def _session(tmp_path: Path) -> Path:
    """A recorded session of the 90 frames of nominal.mp4 at 30 fps, as live records one
    (each frame JPEG-encoded once, its bytes muxed as they are)."""
    avi = tmp_path / "session.avi"
    roundtrip, recorder = MjpgRoundTrip(), SessionRecorder(avi, 30.0)
    for k, frame in enumerate(VideoSource(SAMPLES / "nominal.mp4")):
        image, jpeg = roundtrip(frame.image)
        recorder.write(k, k, k / 30.0, jpeg, image.shape)
    recorder.close()
    return avi


def _poses(path: Path) -> Path:
    """A carrier moving at 20 mm/s along a line at a fixed orientation, 60 poses a second
    over the session's 3 s (as tests/test_live_space.py's sender), as a pose log."""
    q = Rotation.from_euler("zyx", (30, -10, 20), degrees=True).as_quat(scalar_first=True)
    direction = np.array([0.6, -0.48, 0.64])
    samples = [(j / 60.0, (*(100.0 + direction * 20.0 * j / 60.0), *q), j / 60.0)
               for j in range(190)]  # fmt: skip
    return write_pose_log(path, samples)


def test_replay_writes_the_recordings_bytes_wrench_and_contact_points(tmp_path, capsys):
    avi = _session(tmp_path)
    out, bag = tmp_path / "R.csv", tmp_path / "R.mcap"
    rc = main(["replay", str(avi), "--out", str(out), "--mcap", str(bag), "--sensor",
               str(SAMPLES / "nominal.sensor.toml"), "--calib", str(SPACE / "calib.toml"),
               "--eta-deg", "0.5", "--pose-log", str(_poses(tmp_path / "P.pose.csv")),
               "--mount", "0,0,-40,0.9659258,0,0,0.2588190"])  # fmt: skip
    assert rc == 0
    assert capsys.readouterr().out.strip() == f"{out}, {bag}"
    counts, topics = _bag(bag)
    table = _table(out)
    placed = np.flatnonzero(np.isfinite(table["px_mm"]))
    # The clip's contacts get points: 44 of its 90 rows here; 10 is test_live_space's floor.
    assert table["t_s"].size == 90 and placed.size >= 10
    assert counts["/whisker/signals"] == counts["/whisker/image"] == 90
    assert counts["/whisker/contact"] == placed.size
    signals = topics["/whisker/signals"]
    _check_signals(signals, table)  # the contact's fields too (contact_b .. nz)
    # --calib gives the forces with Table I's springs: every trusted row has a wrench.
    assert _check_wrench(topics["/whisker/wrench"], signals, table) == int(table["ok"].sum())
    # The images: the bytes stored in the recording, read back independently.
    stored = _raw_frames(avi)
    assert len(stored) == 90
    assert [bytes(m.data) for _, m in topics["/whisker/image"]] == stored
    for (log_ns, msg), i in zip(topics["/whisker/contact"], placed, strict=True):
        assert log_ns == signals[i][0] and msg.header.frame_id == "world"
        p = msg.point
        # Exact: the point is the row's printed mm over 1000, the same division.
        assert (p.x, p.y, p.z) == tuple(table[k][i] / 1000.0 for k in ("px_mm", "py_mm",
                                                                        "pz_mm"))


class _StopAfter:
    """A stdout for the JSON lines that stops the session at its ``n``-th line, as Ctrl-C
    does (the session's signal handler calls stop with the signal's name)."""

    def __init__(self, n: int):
        self.n, self.lines, self.session = n, 0, None

    def write(self, text: str) -> None:
        self.lines += text.count("\n")
        if self.lines >= self.n:
            self.session.stop("SIGINT")

    def flush(self) -> None:
        pass


def test_live_without_recording_and_a_stop_keeps_the_bag(tmp_path):
    out, bag = tmp_path / "L.csv", tmp_path / "L.mcap"
    stdout = _StopAfter(5)
    config = LiveConfig(mode="every", jsonl=True, controls=False, handle_signals=False,
                        mcap=bag)  # fmt: skip
    session = LiveSession(PlaybackSource(CLIP, 1000.0), load_sensor(CLIP_SENSOR), out, config,
                          stdout)  # fmt: skip
    stdout.session = session
    rep = session.run()
    assert rep.stopped_by == "SIGINT" and rep.rows == 5
    counts, topics = _bag(bag)
    assert counts == {"/whisker/signals": 5, "/whisker/image": 5}  # no springs: no wrench
    _check_signals(topics["/whisker/signals"], _table(out))
    # No recording: the frames as processed (OpenCV's decode of the clip) encoded once at
    # JPEG quality 90, byte for byte; decoded again they differ from the frames by that
    # encoding only: mean under 2 DN, max under 64 DN (measured 1.24-1.26 and 33-38).
    for (_, msg), frame in zip(topics["/whisker/image"], VideoSource(CLIP), strict=False):
        data = bytes(msg.data)
        ok, made = cv2.imencode(".jpg", frame.image, [cv2.IMWRITE_JPEG_QUALITY, 90])
        assert ok and data == made.tobytes()
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        diff = np.abs(image.astype(int) - frame.image.astype(int))
        assert image.shape == frame.image.shape and diff.mean() < 2 and diff.max() < 64


def test_a_bag_not_finished_leaves_the_old_file(tmp_path):
    path = tmp_path / "B.mcap"
    path.write_bytes(b"old")
    columns = ("frame", "t_s", "phi_deg", "ok", "note")
    with pytest.raises(BagError, match=r"B\.mcap: row 3, column t_s: '' is not a time"):
        with BagStream(path, columns) as stream:
            stream.write_row([0, "0.000000", "1.5", 1, ""])
            stream.write_row([1, "", "", 0, "lost"])  # a row without a time
    assert path.read_bytes() == b"old" and sorted(tmp_path.iterdir()) == [path]
    with BagStream(path, columns) as stream:
        stream.write_row([0, "0.000001", "", 0, "rest"])
    counts, topics = _bag(path)
    assert counts == {"/whisker/signals": 1}
    ((log_ns, msg),) = topics["/whisker/signals"]
    assert log_ns == 1000 and math.isnan(msg.phi_deg) and not msg.ok  # 1 us; empty: NaN


def test_live_and_replay_need_the_extra_before_they_start(tmp_path):
    out = tmp_path / "T.csv"
    code = f"""
import sys
for m in ("mcap", "mcap_ros2"):
    sys.modules[m] = None
import camwhisker.cli
for cmd in (["live", {str(CLIP)!r}, "--playback-fps", "1000"], ["replay", "S.avi"]):
    rc = camwhisker.cli.main([*cmd, "--sensor", {str(CLIP_SENSOR)!r}, "--out", {str(out)!r},
                              "--mcap", {str(tmp_path / "T.mcap")!r}])
    print("rc", rc)
"""
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
                         timeout=60)  # fmt: skip
    assert run.stdout.splitlines() == ["rc 2", "rc 2"], run.stderr
    assert run.stderr.count("pip install 'camwhisker[ros]'") == 2
    assert not out.exists() and sorted(tmp_path.iterdir()) == []  # stopped before the session


def _hold_images(monkeypatch, maxsize: int) -> threading.Event:
    """The bag's writer stalled on its first image until the event is set, as on a disk
    that stalls, with a queue of ``maxsize`` rows; returns the event."""
    released = threading.Event()
    write_image = BagStream.write_image

    def held(self, t_s, jpeg):
        released.wait(10.0)  # set at the last row; 10 s: a broken test still ends
        write_image(self, t_s, jpeg)

    monkeypatch.setattr(BagStream, "write_image", held)
    monkeypatch.setattr(camwhisker.live.loop, "BagThread",
                        functools.partial(BagThread, maxsize=maxsize))  # fmt: skip
    return released


@pytest.mark.parametrize("maxsize", [90, 3])
def test_a_stalled_writer_never_stalls_the_loop_and_the_bag_is_whole(tmp_path, monkeypatch,
                                                                     maxsize):  # fmt: skip
    released = _hold_images(monkeypatch, maxsize)
    out, bag = tmp_path / "L.csv", tmp_path / "L.mcap"
    frames: list[int] = []

    def on_row(row):  # after the row's put: the 12th releases the writer
        frames.append(row["frame"])
        if len(frames) == 12:
            released.set()

    config = LiveConfig(mode="every", controls=False, handle_signals=False, mcap=bag,
                        on_row=on_row)  # fmt: skip
    rep = LiveSession(PlaybackSource(CLIP, 1000.0), load_sensor(CLIP_SENSOR), out, config).run()
    # Every row went out while the writer was stuck on the first: the loop did not wait.
    assert rep.rows == len(frames) == 12 and rep.stopped_by == "end of input"
    meta = json.loads(out.with_suffix(".json").read_text())
    counts, topics = _bag(bag)  # finished: it has its summary
    written, dropped = meta["mcap"]["rows"], meta["mcap"]["dropped"]
    assert counts == {"/whisker/signals": written, "/whisker/image": written}
    assert written + dropped == 12
    if maxsize == 90:  # room for all: each row in the bag once the writer goes on
        assert dropped == 0 and not rep.problems
    else:  # the one being written and maxsize queued are kept, no more
        assert dropped >= 12 - 1 - maxsize
        assert f"{dropped} row(s) not in the MCAP bag" in " ".join(rep.problems)
    # The rows kept are the table's, in order, each message equal to its row.
    signals = topics["/whisker/signals"]
    kept = [int(msg.frame) for _, msg in signals]
    assert kept == sorted(kept) and set(kept) <= set(frames)
    _check_signals(signals, {c: v[kept] for c, v in _table(out).items()})
    assert not [p.name for p in tmp_path.iterdir() if ".tmp" in p.name]


def test_a_failed_write_stops_the_session_and_keeps_the_old_bag(tmp_path, monkeypatch):
    out, bag = tmp_path / "L.csv", tmp_path / "L.mcap"
    bag.write_bytes(b"an older file")
    write_row = BagStream.write_row

    def full(self, cells):
        if self.rows == 2:
            raise OSError(28, "No space left on device")
        write_row(self, cells)

    monkeypatch.setattr(BagStream, "write_row", full)
    config = LiveConfig(mode="every", controls=False, handle_signals=False, mcap=bag)
    session = LiveSession(PlaybackSource(CLIP, 1000.0), load_sensor(CLIP_SENSOR), out, config)
    with pytest.raises(OSError, match="No space left"):
        session.run()
    # Raised at the next row or at the end; the bag is not half written: the old file stays.
    assert bag.read_bytes() == b"an older file"
    assert not [p.name for p in tmp_path.iterdir() if ".tmp" in p.name]
