"""Live processing: playback at camera rate, OpenCV capture, drops, recording, unplugs.

Every run uses the bundled 90-frame nominal clip (1280 x 720). The machine is
shared and loaded, so nothing here asserts a wall-clock time; the checks are
counts and invariants that hold at any speed:

- "latest": the backlog is at most one frame; each drop is one missing
  sequence number; processed + dropped = frames in the file;
- playback: frame k is never read before t0 + k / fps on the monotonic
  clock, so the measured rate cannot beat the clock;
- a recorded session reprocessed, by replay or by batch, gives the live table
  byte for byte (both read the session's timestamps file).
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
import os
import socket
import sys
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest

from camwhisker.io.sources import VideoSource, read_timestamps, timestamps_path
from camwhisker.live.capture import SourceCapture
from camwhisker.live.loop import LiveConfig, LiveSession, reprocess_session, run_live
from camwhisker.live.playback import PlaybackSource
from camwhisker.run.batch import run_batch
from camwhisker.sensor.file import load_sensor
from camwhisker.vision.stream import GAP_REASON, live_track

# Plays video at camera rate or times a live loop: run alone (README's test command).
pytestmark = pytest.mark.timing

SAMPLES = Path(__file__).resolve().parents[1] / "sample_frames"
CLIP = SAMPLES / "nominal.mp4"
CLIP_FRAMES = 90
#: t_s is written with 6 decimals.
CSV_ROUNDING_S = 1e-6


@pytest.fixture(scope="module")
def sensor():
    return load_sensor(SAMPLES / "nominal.sensor.toml")


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _check_latest(session: LiveSession, rep, n_file: int) -> None:
    g = rep.grabber
    assert g["max_depth"] <= 1  # the backlog never grows
    gaps = int(np.sum(np.diff(session.seqs) - 1))
    assert g["dropped"] == gaps == rep.seq_gaps  # every drop is one missing seq
    assert rep.rows + g["dropped"] == g["grabbed"] == n_file
    assert session.seqs[-1] == n_file - 1  # the newest frame is never the one dropped at the end


@pytest.mark.parametrize("fps", [30.0, 60.0, 120.0])
def test_playback_latest_mode(tmp_path, sensor, fps):
    cap = PlaybackSource(CLIP, fps)
    out = tmp_path / "live.csv"
    avi = tmp_path / "s.avi" if fps == 30.0 else None  # latest-mode recording, once
    session = LiveSession(cap, sensor, out, LiveConfig(mode="latest", record=avi,
                                                       controls=False))  # fmt: skip
    rep = session.run()
    _check_latest(session, rep, CLIP_FRAMES)
    assert rep.grabber["left_at_stop"] == 0
    if avi is not None:  # the recording reprocessed, by replay and by batch: the same table
        again = reprocess_session(avi, sensor, tmp_path / "again.csv")
        assert again.read_bytes() == out.read_bytes()
        run_batch(avi, sensor, tmp_path / "batch.csv", progress=False)
        assert (tmp_path / "batch.csv").read_bytes() == out.read_bytes()
    assert rep.gaps == 0 and rep.stopped_by == "end of input"
    rows = _rows(out)
    assert len(rows) == rep.rows and [int(r["frame"]) for r in rows] == list(range(rep.rows))
    t = np.array([float(r["t_s"]) for r in rows])
    assert t[0] == 0.0 and np.all(np.diff(t) > 0)
    # released on the clock: frame seq is read no earlier than t0 + seq / fps
    first = rep.grabber["first_t_s"]  # the clock time of the row with t_s = 0
    seqs = np.array(session.seqs)
    assert np.all(first + t >= cap.t0_s + seqs / fps - CSV_ROUNDING_S)
    # so the measured rate cannot beat the clock
    n = rep.grabber["frames"]
    assert rep.grabber["fps_measured"] <= (n - 1) / (cap.t0_s + (n - 1) / fps - first) + 1e-6
    assert rep.rows_ok >= 0.5 * rep.rows
    p = rep.processing
    assert p["n"] == rep.rows and 0 < p["p50_ms"] <= p["p99_ms"] <= p["max_ms"]
    # capture to result includes the processing itself
    assert rep.end_to_end["p50_ms"] >= p["p50_ms"]
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["dropped"] == rep.grabber["dropped"]
    assert meta["latency"]["processing"]["p99_ms"] == p["p99_ms"]
    assert meta["input"]["kind"] == "playback" and meta["input"]["rate_fps"] == fps


def test_opencv_capture_latest_mode(tmp_path, sensor):
    """A plain cv2.VideoCapture on the file is a source too; it ends, it does not fail."""
    session = LiveSession(cv2.VideoCapture(str(CLIP)), sensor, tmp_path / "cv.csv",
                          LiveConfig(mode="latest", controls=False))  # fmt: skip
    rep = session.run()
    _check_latest(session, rep, CLIP_FRAMES)
    assert rep.grabber["failed_reads"] == 0 and rep.stopped_by == "end of input"


def test_recorded_session_reprocesses_to_the_same_rows(tmp_path, sensor):
    """Every-frame mode through cv2.VideoCapture, recorded, with UDP and JSON lines, and
    the forces (the spring model): live, replay and batch write the same table."""
    from camwhisker.sensor.springs import suspension_stiffness

    springs = suspension_stiffness()
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(1.0)
    stdout = io.StringIO()
    out, avi = tmp_path / "live.csv", tmp_path / "session.avi"
    config = LiveConfig(mode="every", record=avi, udp_port=rx.getsockname()[1], jsonl=True,
                        controls=False, springs=springs)  # fmt: skip
    session = LiveSession(cv2.VideoCapture(str(CLIP)), sensor, out, config, stdout)
    rep = session.run()
    assert rep.rows == CLIP_FRAMES and rep.grabber["dropped"] == 0
    assert session.seqs == list(range(CLIP_FRAMES))
    stamps = read_timestamps(timestamps_path(avi))
    assert [s["video_frame"] for s in stamps] == list(range(CLIP_FRAMES))

    again = reprocess_session(avi, sensor, tmp_path / "again.csv", springs=springs)
    assert again.read_bytes() == out.read_bytes()

    batch = run_batch(avi, sensor, tmp_path / "batch.csv", progress=False, springs=springs)
    assert batch.frames == CLIP_FRAMES and batch.problems == []
    assert (tmp_path / "batch.csv").read_bytes() == out.read_bytes()  # t_s too: the session's
    assert json.loads(batch.sidecar.read_text())["time_source"].startswith("session timestamps")
    live_rows = _rows(out)
    assert sum(r["ok"] == "1" for r in live_rows) >= 0.9 * CLIP_FRAMES

    lines = [json.loads(x) for x in stdout.getvalue().splitlines()]
    got = [json.loads(rx.recv(4096)) for _ in range(CLIP_FRAMES)]
    rx.close()
    assert len(lines) == CLIP_FRAMES and got == lines
    assert [m["frame"] for m in lines] == list(range(CLIP_FRAMES))
    for m, r in zip(lines, live_rows, strict=True):
        assert m["ok"] == int(r["ok"])
        if m["ok"]:
            assert math.isclose(m["phi_deg"], float(r["phi_deg"]), abs_tol=1e-5)
            # The forces as the table has them (5 significant digits), F_z = k_z dz.
            assert math.isclose(m["fz_mN"], float(r["fz_mN"]), rel_tol=1e-4)
            assert math.isclose(float(r["fz_mN"]), 1e3 * springs.k_z_n_per_mm
                                * float(r["dz_mm"]), rel_tol=1e-3, abs_tol=1e-3)  # fmt: skip
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["springs"]["k_z_n_per_mm"] == springs.k_z_n_per_mm
    assert meta["columns"][-2:] == ["fz_mN", "mb_Nmm"]
    assert meta["udp"]["sent"] == CLIP_FRAMES
    assert meta["recording"]["frames"] == CLIP_FRAMES


class FlakyCapture:
    """A capture that fails reads ``start`` .. ``start + len(kinds) - 1`` (a simulated
    unplug): each failing read returns nothing ("none"), an empty image ("empty") or
    raises OSError ("raise"); ``forever`` keeps failing from ``start`` on."""

    def __init__(self, inner, start: int, kinds=(), forever: bool = False):
        self.inner, self.start, self.kinds, self.forever = inner, start, list(kinds), forever
        self.calls = 0
        self.reopens = 0

    @property
    def ended(self):
        return self.inner.ended

    def read(self):
        k = self.calls - self.start
        self.calls += 1
        if k >= 0 and (self.forever or k < len(self.kinds)):
            kind = "none" if self.forever else self.kinds[k]
            if kind == "raise":
                raise OSError("No such device (simulated unplug)")
            if kind == "empty":
                return True, np.zeros((0, 0, 3), np.uint8)
            return False, None
        return self.inner.read()

    def reopen(self):
        self.reopens += 1
        return True

    def release(self):
        self.inner.release()


def test_unplug_mid_stream_reconnects_and_flags_the_gap(tmp_path, sensor, caplog):
    kinds = ["none", "empty", "raise", "raise", "none"]
    cap = FlakyCapture(SourceCapture(CLIP), 20, kinds)
    out, avi = tmp_path / "live.csv", tmp_path / "s.avi"
    config = LiveConfig(mode="every", record=avi, backoff_s=0.005, max_frames=40,
                        controls=False)  # fmt: skip
    with caplog.at_level(logging.WARNING, logger="camwhisker.live.grabber"):
        rep = run_live(cap, sensor, out, config)
    attempts = [m for m in caplog.messages if "reconnect attempt" in m]
    assert len(attempts) == len(kinds) and "1/8" in attempts[0] and "5/8" in attempts[-1]
    assert any("back after 5 failed read(s)" in m for m in caplog.messages)
    assert cap.reopens == len(kinds)
    g = rep.grabber
    assert g["failed_reads"] == len(kinds) and g["reconnects"] == 1 and not g["lost"]
    rows = _rows(out)
    assert len(rows) == 40 and rep.gaps == len(kinds)
    gap = [i for i, r in enumerate(rows) if r["note"] == GAP_REASON]
    assert gap == list(range(20, 25))
    assert all(rows[i]["ok"] == "0" and rows[i]["phi_deg"] == "" for i in gap)
    assert all(r["ok"] == "1" for r in rows[25:])  # tracking carries on after the gap
    assert any("raised OSError" in e for e in g["errors"])
    # the recording keeps the gap rows, and reprocessing gives them back
    assert reprocess_session(avi, sensor, tmp_path / "again.csv").read_bytes() == out.read_bytes()


def test_camera_lost_for_good_ends_cleanly(tmp_path, sensor):
    cap = FlakyCapture(SourceCapture(CLIP), 5, forever=True)
    out = tmp_path / "live.csv"
    config = LiveConfig(mode="every", backoff_s=0.001, max_reconnects=3, controls=False)
    rep = run_live(cap, sensor, out, config)
    assert rep.grabber["lost"] and rep.stopped_by == "capture lost"
    assert rep.rows == 5 + 4 and rep.gaps == 4  # the 4th failure gives up
    assert cap.reopens == 3
    assert "capture lost after 3 reconnect attempts" in rep.problems
    rows = _rows(out)
    assert len(rows) == 9 and [r["ok"] for r in rows[5:]] == ["0"] * 4
    assert json.loads(out.with_suffix(".json").read_text())["stopped_by"] == "capture lost"


class CommandingCapture:
    """Sends the session a command when the ``at``-th frame is read (as a key would)."""

    def __init__(self, inner, at: int, command: str):
        self.inner, self.at, self.cmd = inner, at, command
        self.session = None
        self.calls = 0

    @property
    def ended(self):
        return self.inner.ended

    def read(self):
        if self.calls == self.at:
            self.session.command(self.cmd)
        self.calls += 1
        return self.inner.read()

    def release(self):
        self.inner.release()


@pytest.mark.parametrize("command", ["rezero", "redetect"])
def test_commands_are_recorded_and_replayed(tmp_path, sensor, command):
    cap = CommandingCapture(SourceCapture(CLIP), 30, command)
    out, avi = tmp_path / "live.csv", tmp_path / "s.avi"
    session = LiveSession(cap, sensor, out, LiveConfig(mode="every", record=avi, max_frames=45,
                                                       controls=False))  # fmt: skip
    cap.session = session
    rep = session.run()
    assert len(rep.events) == 1 and rep.events[0]["event"] == command
    k = rep.events[0]["frame"]
    assert 1 <= k < 45  # the command comes from another thread: any row after the first
    row = _rows(out)[k]
    if command == "rezero":  # at rest it reads zero exactly; deflected, it is refused
        assert (row["phi_deg"], row["ok"]) == ("0.00000", "1") or (
            row["ok"] == "0" and row["note"].startswith("re-zero failed: features not found")
        )
    else:
        assert row["ok"] == "1"
    assert read_timestamps(timestamps_path(avi))[k]["event"] == command
    assert reprocess_session(avi, sensor, tmp_path / "again.csv").read_bytes() == out.read_bytes()


def test_rezero_and_redetect_in_the_processor(sensor):
    """Frames 0-8 of the clip are at rest, 9-12 at phi = 29.1 deg (truth)."""
    frames = [f.image for f, _ in zip(VideoSource(CLIP), range(14), strict=False)]
    events = {5: "rezero", 10: "rezero", 12: "redetect"}
    rows = list(live_track(((im, events.get(i, "")) for i, im in enumerate(frames)), sensor))
    assert [r.frame for r in rows] == list(range(14))
    assert rows[5].ok and (rows[5].dz_mm, rows[5].phi_deg) == (0.0, 0.0)  # new rest frame
    assert rows[6].phi_deg != 0.0
    # deflected: no rest reference can be found there; the old one stays in use
    assert not rows[10].ok and rows[10].reason.startswith("re-zero failed")
    assert rows[11].ok and abs(rows[11].phi_deg - 29.14) < 0.1
    assert rows[12].ok and abs(rows[12].phi_deg - 29.14) < 0.1
    gapped = list(live_track([(frames[0], ""), (None, "gap"), (frames[1], "")], sensor))
    assert [r.ok for r in gapped] == [True, False, True] and gapped[1].reason == GAP_REASON


def test_session_keeps_its_start_up_objects_out_of_full_collections(tmp_path, sensor, monkeypatch):
    """During the loop the objects alive at its start are frozen (a full collection walks
    none of them: with them it took ~50 ms here, longer than a frame); afterwards the
    process's collector is as it was."""
    import gc

    frozen = []
    row = LiveSession._row

    def counting_row(self, *args, **kwargs):
        frozen.append(gc.get_freeze_count())
        return row(self, *args, **kwargs)

    monkeypatch.setattr(LiveSession, "_row", counting_row)
    tracked_before = len(gc.get_objects())
    session = LiveSession(PlaybackSource(CLIP, 120.0), sensor, tmp_path / "gc.csv",
                          LiveConfig(controls=False, max_frames=5))  # fmt: skip
    rep = session.run()
    assert rep.rows == 5 and len(frozen) == 5
    # Everything the collector tracked before the session (numpy, OpenCV, numba, the
    # package: tens of thousands of objects) is frozen on every row.
    assert min(frozen) >= 0.9 * tracked_before > 10_000
    assert gc.get_freeze_count() == 0


def test_quit_command_stops_the_session(tmp_path, sensor):
    cap = CommandingCapture(PlaybackSource(CLIP, 60.0), 10, "quit")
    session = LiveSession(cap, sensor, tmp_path / "q.csv", LiveConfig(controls=False))
    cap.session = session
    rep = session.run()
    assert rep.stopped_by == "quit" and rep.rows < CLIP_FRAMES
    assert len(_rows(tmp_path / "q.csv")) == rep.rows


def test_terminal_keys(tmp_path, sensor, monkeypatch):
    """r / d / q from a terminal (a pseudo-terminal here); the terminal is restored."""
    import pty
    import termios

    master, slave = pty.openpty()
    before = termios.tcgetattr(slave)
    tty_in = os.fdopen(slave, "r")
    monkeypatch.setattr(sys, "stdin", tty_in)
    cap = PlaybackSource(CLIP, 30.0, loop=True)  # never ends by itself
    # typed once the session has put the terminal in cbreak mode; q ends the session
    typist = threading.Timer(1.0, os.write, (master, b"rdq"))
    typist.start()
    try:
        # duration_s only guards the test from hanging: q must come long before
        rep = run_live(cap, sensor, tmp_path / "k.csv", LiveConfig(controls=None, duration_s=30))
        typist.join()
        after = termios.tcgetattr(slave)
    finally:
        tty_in.close()
        os.close(master)
    assert rep.stopped_by == "quit"
    assert after == before
    assert all(e["event"] in ("rezero", "redetect") for e in rep.events)
