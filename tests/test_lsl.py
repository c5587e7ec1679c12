"""Lab Streaming Layer on loopback: the live rows and events out (``--lsl``), poses in
(``--base-lsl``).

LSL is kept to this machine (an ``lsl_api.cfg`` named by LSLAPICFG, set before pylsl
starts: no IPv6, discovery within the machine, 127.0.0.1 the only peer). The bundled
clips play at camera rate in "every" mode, so every frame gives a row at any speed.
"""

from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest

_CFG = Path(tempfile.mkdtemp(prefix="camwhisker-lsl-")) / "lsl_api.cfg"
_CFG.write_text("[ports]\nIPv6 = disable\n[multicast]\nResolveScope = machine\n"
                "[lab]\nKnownPeers = {127.0.0.1}\n[log]\nlevel = -3\n")  # fmt: skip
os.environ["LSLAPICFG"] = str(_CFG)

import pylsl  # noqa: E402 - after LSLAPICFG: liblsl reads it once, when it starts

from camwhisker.cli.parser import main  # noqa: E402
from camwhisker.contact.calibrate import read_calibration  # noqa: E402
from camwhisker.io.poses import QUAT_NORM_TOL  # noqa: E402
from camwhisker.live.base import read_pose_log_samples  # noqa: E402
from camwhisker.live.loop import LiveConfig, LiveSession  # noqa: E402
from camwhisker.live.lsl import LslBaseReceiver, LslError, lsl_module  # noqa: E402
from camwhisker.live.playback import PlaybackSource  # noqa: E402
from camwhisker.sensor.file import load_sensor  # noqa: E402

# Plays video at camera rate: run alone (README's test command).
pytestmark = pytest.mark.timing

SAMPLES = Path(__file__).resolve().parents[1] / "sample_frames"
MJPG = SAMPLES / "nominal_mjpg.avi"  # 12 frames, 30 fps
MJPG_FRAMES = 12
#: The issue's bound on a sample's stamp against its row's capture time (s).
STAMP_TOL_S = 1e-3
#: Bound on waits for a stream (s): a guard against a hang, not a measurement.
WAIT_S = 5.0
#: Frames after which the test asks for a re-zero and a re-detect (they land one later).
REZERO_AT, REDETECT_AT = 3, 6


def _name(what: str) -> str:
    """A stream name no other run on the machine uses."""
    return f"camwhisker-test-{what}-{os.getpid()}"


def _inlet(name: str):
    found = pylsl.resolve_byprop("name", name, 1, WAIT_S)
    assert found, f"no LSL stream {name}"
    # recover=False: a pull after the outlet closed raises LostError, ending the reader.
    inlet = pylsl.StreamInlet(found[0], recover=False)
    inlet.open_stream(WAIT_S)
    return inlet


def _channels(inlet) -> tuple[list[str], list[str]]:
    """The labels and units of a stream's channels, from its description."""
    info = inlet.info()  # held: the description's elements live in it
    ch = info.desc().child("channels").first_child()
    labels, units = [], []
    while not ch.empty():
        labels.append(ch.child_value("label"))
        units.append(ch.child_value("unit"))
        ch = ch.next_sibling()
    return labels, units


def _read(inlet, into: list, stop: threading.Event) -> None:
    """Pull (sample, stamp) pairs until the outlet closes (or ``stop`` after WAIT_S)."""
    while not stop.is_set():
        try:
            samples, stamps = inlet.pull_chunk(timeout=0.0)
        except pylsl.util.LostError:
            return
        into.extend(zip(samples, stamps, strict=True))
        time.sleep(0.005)


def _table(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _cell(text: str) -> float:
    return math.nan if text == "" else float(text)


def test_live_rows_and_events_reach_an_inlet_stamped_with_their_capture_times(tmp_path):
    sensor = load_sensor(SAMPLES / "nominal_mjpg.sensor.toml")
    name = _name("rows")
    out = tmp_path / "live.csv"
    first_row_lsl: list[float] = []
    session = None

    def hook(row):
        first_row_lsl.append(pylsl.local_clock())
        if row["frame"] == REZERO_AT:
            session.command("rezero")
        elif row["frame"] == REDETECT_AT:
            session.command("redetect")

    config = LiveConfig(mode="every", controls=False, handle_signals=False, lsl=name,
                        on_row=hook)  # fmt: skip
    session = LiveSession(PlaybackSource(MJPG, 30.0), sensor, out, config)
    rows_in, events_in = _inlet(name), _inlet(name + "-events")
    labels, units = _channels(rows_in)  # while the outlet is open
    correction = rows_in.time_correction(WAIT_S)  # ~0 on one machine; applied as a reader does
    rows, events = [], []
    stop = threading.Event()
    readers = [threading.Thread(target=_read, args=(inlet, got, stop), daemon=True)
               for inlet, got in ((rows_in, rows), (events_in, events))]  # fmt: skip
    for r in readers:
        r.start()
    before = pylsl.local_clock()
    rep = session.run()
    for r in readers:
        r.join(WAIT_S)
    stop.set()
    table = _table(out)
    meta = json.loads(out.with_suffix(".json").read_text())["lsl"]
    assert rep.rows == len(table) == MJPG_FRAMES
    # The channels: the table's numeric columns, labelled, with units.
    columns = [c for c in table[0] if c != "note"]
    assert labels == columns == [c for c, _ in meta["channels"]]
    assert dict(zip(labels, units, strict=True))["dz_mm"] == "mm"
    # Every row, in order, each value the table's cell (NaN where empty): exact, same text.
    assert len(rows) == MJPG_FRAMES and meta["rows"] == MJPG_FRAMES
    for (sample, _), r in zip(rows, table, strict=True):
        want = [_cell(r[c]) for c in columns]
        assert all((math.isnan(a) and math.isnan(b)) or a == b
                   for a, b in zip(sample, want, strict=True)), (sample, want)  # fmt: skip
    # Stamps: the capture time on LSL's clock. The first frame's (t_s = 0) lies between the
    # session's start and its first row; each stamp less it is the row's t_s.
    t0 = meta["t0_lsl_s"]
    assert before <= t0 <= first_row_lsl[0]
    for (_, stamp), r in zip(rows, table, strict=True):
        assert abs(stamp + correction - t0 - float(r["t_s"])) <= STAMP_TOL_S
    # The events, on the marker stream, stamped as the rows they took effect at.
    assert [s[0] for s, _ in events] == ["rezero", "redetect"] and meta["events"] == 2
    by_frame = {int(r["frame"]): t for r, (_, t) in zip(table, rows, strict=True)}
    for (_, stamp), frame in zip(events, (REZERO_AT + 1, REDETECT_AT + 1), strict=True):
        assert abs(stamp - by_frame[frame]) <= STAMP_TOL_S
    assert [e["frame"] for e in rep.events] == [REZERO_AT + 1, REDETECT_AT + 1]


def _push_poses(outlet, session_done: threading.Event, pushed: list) -> None:
    """Poses at 100 Hz, stamped 5 ms before they are pushed (as a robot stamps the time the
    pose was measured), a turn about z growing; a bad one (quaternion norm 2) once."""
    k = 0
    while not session_done.is_set():
        a = 0.01 * k
        pose = [1.0 + k, 2.0, 3.0 - 0.5 * k, math.cos(a / 2), 0.0, 0.0, math.sin(a / 2)]
        stamp = pylsl.local_clock() - 0.005
        if k == 5:
            outlet.push_sample([0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0], stamp - 0.001)
        outlet.push_sample(pose, stamp)
        pushed.append((stamp, tuple(pose)))
        k += 1
        time.sleep(0.01)


def test_base_poses_from_an_lsl_stream_land_in_the_pose_log_on_the_camera_clock(tmp_path):
    name = _name("base")
    info = pylsl.StreamInfo(name, "Pose", 7, 100.0, pylsl.cf_double64, name)
    outlet = pylsl.StreamOutlet(info)
    out = tmp_path / "live.csv"
    calib = SAMPLES / "space" / "calib.toml"
    config = LiveConfig(mode="every", controls=False, handle_signals=False, max_frames=30,
                        calib=read_calibration(calib), calib_path=str(calib), eta_deg=0.5,
                        base_lsl=name, lsl=_name("out"))  # fmt: skip
    session = LiveSession(PlaybackSource(SAMPLES / "nominal.mp4", 30.0),
                          load_sensor(SAMPLES / "nominal.sensor.toml"), out, config)
    assert session.config.base_poses  # seven channels: poses
    done, pushed = threading.Event(), []
    sender = threading.Thread(target=_push_poses, args=(outlet, done, pushed), daemon=True)
    sender.start()
    rep = session.run()
    done.set()
    sender.join(WAIT_S)
    meta = json.loads(out.with_suffix(".json").read_text())
    base = meta["contact"]["base"]
    assert rep.rows == 30 and base["kind"] == "poses" and base["lsl_stream"] == name
    assert base["rejected"] == {
        f"channels qw-qz: the quaternion's norm is not 1 within {QUAT_NORM_TOL:g}": 1}
    samples = read_pose_log_samples(tmp_path / "live.pose.csv")
    # 1 s of frames at 100 Hz: most of the ~100 poses pushed while the session received
    assert len(samples) == base["received"] >= 50
    # Each logged pose is one pushed, exactly, in order (the first ones received may come
    # from before the first frame); its time the pushed stamp on the camera clock: less
    # the first frame's time (t0 on LSL's clock), within the clock correction (~0 here),
    # the two measurements of LSL's clock against the monotonic one (inlet's, outlet's;
    # ~1 us apart) and the log's 1 ns rounding.
    t0 = meta["lsl"]["t0_lsl_s"]
    k0 = [p for _, p in pushed].index(samples[0][1])
    tol = (abs(base["time_correction_s"]) + abs(base["clock_offset_s"]
                                                 - meta["lsl"]["clock_offset_s"]) + 1e-8)
    assert len(pushed) - k0 >= len(samples)  # every logged pose is compared
    for (t, pose, _), (stamp, sent) in zip(samples, pushed[k0:], strict=False):
        assert pose == sent
        assert abs(t + t0 - stamp) <= tol


def test_base_stream_errors_are_named(tmp_path):
    name = _name("two")
    outlet = pylsl.StreamOutlet(pylsl.StreamInfo(name, "Pose", 2, 0, pylsl.cf_double64, name))
    with pytest.raises(LslError, match=f"--base-lsl {name}: 2 channel"):
        LslBaseReceiver(name, resolve_s=WAIT_S)
    del outlet
    # Not found: said after the wait given (0.2 s), well within the guard.
    with pytest.raises(LslError, match="no LSL stream of that name found within 0.2 s"):
        LslBaseReceiver(_name("none"), resolve_s=0.2)


def test_lsl_options_are_checked(tmp_path, capsys, monkeypatch):
    calib = str(SAMPLES / "space" / "calib.toml")
    out = str(tmp_path / "o.csv")
    args = ["live", str(MJPG), "--out", out, "--calib", calib, "--base-lsl", "robot"]
    assert main([*args, "--base-udp", "0"]) == 2
    assert "no --base-udp or --base-offset-s with it" in capsys.readouterr().err
    assert main([*args, "--base-offset-s", "0.1"]) == 2
    assert "no --base-udp or --base-offset-s with it" in capsys.readouterr().err
    # Without pylsl: a clear error naming the extra, before anything is opened.
    monkeypatch.setitem(sys.modules, "pylsl", None)
    with pytest.raises(LslError, match=r"pip install 'camwhisker\[lsl\]'"):
        lsl_module()
    assert main(["live", str(MJPG), "--out", out, "--lsl", "w"]) == 2
    assert "pylsl, which is not installed: pip install 'camwhisker[lsl]'" in capsys.readouterr().err
    assert not (tmp_path / "o.csv").exists()


def test_the_package_imports_without_loading_pylsl():
    code = ("import sys, camwhisker, camwhisker.cli, camwhisker.live.loop, camwhisker.live.lsl; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'pylsl'))")
    root = Path(__file__).resolve().parents[1]
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root,
                         env={"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin"},
                         timeout=60)  # fmt: skip
    assert run.stdout.strip() == "[]", run.stderr  # pylsl: imported only when a stream opens
