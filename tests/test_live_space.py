"""Live with base poses in space (issue #60): datagrams, the pose log, the contact point.

- Datagrams: a pose ``{t_s, x_mm, y_mm, z_mm, qw, qx, qy, qz}`` or a position
  ``{t_s, x_mm}``, one kind per session; the other kind, a quaternion whose norm is
  not 1, NaN or a missing key are dropped and counted by kind.
- Online against offline: the simulated cylinder runs of ``sample_frames/space`` (signals
  and pose logs, the true clock offsets) through :class:`OnlineContact` with the poses
  handed over as they come, against :func:`contact_rows_in_space` on the whole run.
- A live session: the bundled nominal clip played at camera rate while a sender streams
  a carrier's poses (and bad datagrams) on loopback UDP; the pose log it writes, its
  rows and messages, and replay with that log.
"""

from __future__ import annotations

import csv
import io
import json
import math
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camwhisker.cli.parser import main
from camwhisker.contact.calibrate import read_calibration
from camwhisker.contact.online import BaseFeed, BaseTrack, OnlineContact, PoseTrack
from camwhisker.contact.space import WORLD_COLUMNS, contact_rows_in_space, travel_log
from camwhisker.io.poses import QUAT_NORM_TOL, Mount, read_pose_log
from camwhisker.io.signals import read_signal_table
from camwhisker.live.base import (
    BaseReceiver,
    parse_base_datagram,
    parse_pose_datagram,
    pose_log_path,
    read_pose_log_samples,
    write_pose_log,
)
from camwhisker.live.loop import LiveConfig, LiveSession
from camwhisker.live.playback import PlaybackSource
from camwhisker.sensor.file import load_sensor
from camwhisker.sensor.springs import suspension_stiffness

# Plays video at camera rate or times a live loop: run alone (README's test command).
pytestmark = pytest.mark.timing

SAMPLES = Path(__file__).resolve().parents[1] / "sample_frames"
SPACE = SAMPLES / "space"
CLIP = SAMPLES / "nominal.mp4"
FPS = 30.0
#: Bound on waits for datagrams (s): a guard against a hang, not a measurement.
WAIT_S = 10.0


def _pose_bytes(t, pose) -> bytes:
    keys = ("x_mm", "y_mm", "z_mm", "qw", "qx", "qy", "qz")
    return json.dumps({"t_s": t, **dict(zip(keys, pose, strict=True))}).encode()


def test_pose_datagrams_are_parsed_and_bad_ones_named():
    q = (0.5, 0.5, -0.5, 0.5)
    assert parse_pose_datagram(_pose_bytes(2.5, (1, 2, 3, *q))) == (2.5, (1.0, 2.0, 3.0, *q))
    # A norm off by the tolerance's half: a log's rounding, kept as sent (normalised later).
    near = (1 + QUAT_NORM_TOL / 2, 0.0, 0.0, 0.0)
    assert parse_pose_datagram(_pose_bytes(1, (0, 0, 0, *near)))[1][3] == near[0]
    bad = {
        b'{"t_s": 1, "x_mm": 2}': "a position {t_s, x_mm} where poses are expected",
        _pose_bytes(1, (0, 0, 0, 1.01, 0, 0, 0)): "the quaternion's norm is not 1",
        _pose_bytes(1, (0, math.nan, 0, *q)): "key y_mm: missing or not a finite",
        b'{"t_s": 1, "x_mm": 0, "y_mm": 0, "z_mm": 0, "qw": 1, "qx": 0, "qy": 0}': "key qz",
        b"[1]": "not a JSON object",
    }
    for data, why in bad.items():
        with pytest.raises(ValueError, match=why.replace("{", r"\{").replace("}", r"\}")):
            parse_pose_datagram(data)
    # A position session refuses a pose (its x_mm is no travel), keeps today's datagrams.
    assert parse_base_datagram(b'{"t_s": 1.5, "x_mm": -2, "v": 3}') == (1.5, -2.0)
    with pytest.raises(ValueError, match="start live with --base-poses"):
        parse_base_datagram(_pose_bytes(1, (0, 0, 0, *q)))


def test_pose_receiver_counts_each_bad_kind():
    rx = BaseReceiver(0, poses=True)
    rx.start()
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sent = [_pose_bytes(1, (0, 0, 0, 1, 0, 0, 0)), b'{"t_s": 2, "x_mm": 1}',
            _pose_bytes(3, (0, 0, 0, 2, 0, 0, 0)), _pose_bytes(4, (1, 0, 0, 1, 0, 0, 0)),
            _pose_bytes(4, (2, 0, 0, 1, 0, 0, 0))]  # fmt: skip
    for data in sent:
        tx.sendto(data, rx.address)
    deadline = time.monotonic() + WAIT_S
    while rx.received + sum(rx.rejected.values()) < len(sent) and time.monotonic() < deadline:
        time.sleep(0.01)
    rx.stop()
    tx.close()
    got = [s[:2] for s in rx.take()]
    assert got == [(1.0, (0, 0, 0, 1, 0, 0, 0)), (4.0, (1, 0, 0, 1, 0, 0, 0))]
    norm = f"keys qw-qz: the quaternion's norm is not 1 within {QUAT_NORM_TOL:g}"
    assert rx.rejected == {"a position {t_s, x_mm} where poses are expected": 1, norm: 1,
                           "t_s not after the previous position's": 1}  # fmt: skip


def test_a_mount_composes_the_carrier_pose_as_a_pose_log_does(tmp_path):
    """The track's sensor poses from a carrier's and a mount equal read_pose_log's (scipy)."""
    rng = np.random.default_rng(3)
    t = np.arange(5) * 0.05
    p = rng.normal(0, 50, (5, 3))
    q = Rotation.random(5, random_state=4).as_quat(scalar_first=True)
    mount = Mount.parse("10,-20,35,0.9238795,0,0.3826834,0")
    path = write_pose_log(tmp_path / "c.pose.csv", [(a, (*b, *c), a) for a, b, c in
                                                    zip(t, p, q, strict=True)])  # fmt: skip
    log = read_pose_log(path, mount)
    track = PoseTrack(mount)
    for a, pose, _ in read_pose_log_samples(path):
        assert track.add(a, pose)
    for tq in (0.0, 0.07, 0.2):
        want_p, want_m = log.at(tq)
        got_p, got_m, _ = track.at(tq)
        # Slerp and composition in closed form against scipy's: float rounding only.
        np.testing.assert_allclose(got_p, want_p[0], atol=1e-9)
        np.testing.assert_allclose(got_m, want_m[0], atol=1e-12)
    assert track.at(0.2 + 0.3) is None  # past MAX_EXTRAPOLATE_S: no pose
    # The turn since the first pose, as the offline check takes it (float rounding only).
    assert track.turn_deg == pytest.approx(log.turn_deg(), abs=1e-6)


#: Rows of a run fed to the online path (~40 s, ~1 s of CPU): its first contacts, slides
#: and pauses; the offline table is made from the whole run (its theta, its onset).
ONLINE_ROWS = 1200


def _online(signals, samples, calib, track=None):
    """The first ONLINE_ROWS rows of OnlineContact fed the run's frames in order, each with
    the pose samples received by its time (as a live session hands them over); ``track``
    a BaseTrack for position samples."""
    feed = BaseFeed(PoseTrack() if track is None else track)
    for sample in samples:
        feed.put(*sample)
    online = OnlineContact(calib, 1 / FPS, base=feed.track)
    ok = np.asarray(signals["ok"], bool)
    rows = []
    for i in range(ONLINE_ROWS):
        t = float(signals["t_s"][i])
        feed.advance(t)
        rows.append(online.update(i, t, signals["phi_deg"][i], signals["dz_mm"][i], ok[i],
                                  (0, 30) if i >= 29 else None, signals["theta_deg"][i]))
    return {k: np.array([r[k] for r in rows], float) for k in rows[0] if k != "doubt"}


def _xyz(cols, names):
    return np.column_stack([np.asarray(cols[k], float) for k in names])


@pytest.mark.parametrize("name", ["h+0run0", "h-30run1"])
def test_online_contact_in_space_agrees_with_the_offline_table(name, tmp_path):
    """Online vs :func:`contact_rows_in_space` on one simulated cylinder run (theta 0 and
    180 deg), the poses given as a session logs them: on the camera clock, each received
    when the base was there (so a frame sees them up to its time and extrapolates past
    the newest, as live does)."""
    calib = read_calibration(SPACE / "calib.toml")
    signals = read_signal_table(SPACE / f"{name}.signals.csv")
    offset = next(r["offset_s"] for r in json.loads((SPACE / "object.json").read_text())["runs"]
                  if r["name"] == name)  # fmt: skip
    poses = read_pose_log(SPACE / f"{name}.pose.csv")
    samples = [(t + offset, (*p, *q), t + offset) for t, p, q in
               zip(poses.t_s, poses.p_mm, poses.quat, strict=True)]  # fmt: skip
    log = write_pose_log(tmp_path / "run.pose.csv", samples)
    offline, run, theta = contact_rows_in_space(signals, read_pose_log(log), calib, 0.0)
    on = _online(signals, read_pose_log_samples(log), calib)
    offline = {k: np.asarray(v)[:ONLINE_ROWS] for k, v in offline.items()}
    p_on, p_off = _xyz(on, WORLD_COLUMNS[:3]), _xyz(offline, WORLD_COLUMNS[:3])
    has_on, has_off = np.isfinite(p_on).all(1), np.isfinite(p_off).all(1)
    both = has_on & has_off
    # Where the offline table places a point, live does too, but for a contact's first
    # frames: live finds the onset from the frames so far, and while phi lingers at ~1.2 deg
    # (h+0run0's first pause, ~100 rows) its GM runs away, its slip test fires and r_hat is
    # empty (the one-axis path's behaviour, tests/test_live_contact.py).
    assert both.sum() >= 0.85 * has_off.sum() and has_off.sum() > 0.6 * ONLINE_ROWS
    # The placement alone: the online point against the offline formula on the online
    # eq. 12 point (its lateral x_hat - x and y_hat), the run's theta and the logged pose
    # interpolated. What differs: theta's running mean (within ~0.3 deg of the run's mean
    # once a few rows are in; at a lateral <= 25 mm, <= 0.15 mm) and the pose extrapolated
    # past the newest sample at the base's stops (<= its speed x the 0.05 s between poses).
    p, m = read_pose_log(log).at(np.asarray(offline["t_s"], float))
    th = math.radians(theta)
    local = (on["x_hat_mm"] - on["x_mm"])[:, None] * [math.cos(th), math.sin(th), 0.0]
    local[:, 2] = on["y_hat_mm"]
    placed = p + np.einsum("nij,nj->ni", m, local)
    err = np.linalg.norm(p_on - placed, axis=1)[has_on]
    assert np.median(err) <= 0.01 and err.max() <= 0.3
    # r_hat is the one-axis online path's, fed the offline travel (the poses projected on
    # the run's theta): within 0.01 mm (3 um seen), the running theta's tiny difference.
    x = travel_log(read_pose_log(log), theta)
    one_axis = _online(signals, [(t, v, t) for t, v in zip(x.t_s, x.x_mm, strict=True)],
                       calib, BaseTrack())  # fmt: skip
    np.testing.assert_allclose(on["r_hat_mm"], one_axis["r_hat_mm"], atol=0.01, equal_nan=True)
    # The point: what is left is the contact distance r_hat, which online finds from the
    # frames so far (tests/test_live_contact.py holds it to batch): |dP| <= |dr| + 0.3 mm.
    dp = np.linalg.norm(p_on - p_off, axis=1)[both]
    dr = np.abs(on["r_hat_mm"] - np.asarray(offline["r_hat_mm"], float))[both]
    assert np.all(dp <= dr + 0.3)
    # The normal: R (-d_s) with theta's running mean against the run's: within 2.5 deg
    # (a contact's first rows, theta from a few noisy rows at phi ~1 deg), 0.05 deg typical.
    n_on, n_off = _xyz(on, WORLD_COLUMNS[3:]), _xyz(offline, WORLD_COLUMNS[3:])
    angle = np.degrees(np.arccos(np.clip(np.sum(n_on * n_off, axis=1), -1, 1)))[both]
    assert np.median(angle) <= 0.05 and angle.max() <= 2.5
    # The travel: once the onset is fixed (phi >= 5 deg), dx from the same frames along
    # nearly the same direction; the extrapolation at the stops as above.
    late = np.asarray(signals["phi_deg"], float)[:ONLINE_ROWS] >= 5.0
    ddx = np.abs(on["dx_mm"] - np.asarray(offline["dx_mm"], float))[late]
    assert np.nanmedian(ddx) <= 0.02 and np.nanmax(ddx) <= 0.3


def _send_poses(cap: PlaybackSource, address, mount_speed, bad: list[bytes]) -> list[tuple]:
    """The robot: a carrier moving along a line at constant orientation, one pose per 1/60 s
    of the video's clock, sent once the playback has released the frame of its time and
    stamped on this machine's monotonic clock (as tests/test_live_contact.py's sender);
    the bad datagrams go out with the 10th frame. Returns the good poses sent."""
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    q = tuple(Rotation.from_euler("zyx", (30, -10, 20), degrees=True).as_quat(scalar_first=True))
    direction = np.array([0.6, -0.48, 0.64])
    sent, k, j, last = [], 0, 0, -math.inf
    while True:
        if cap.released <= k:
            if cap.ended:
                break
            time.sleep(0.0005)
            continue
        out_s = time.monotonic()
        while j / 60.0 < (k + 1) / FPS:
            pos = tuple(float(c) for c in 100.0 + direction * mount_speed * j / 60.0)
            # Later than the last: a frame released late is followed by one released early.
            stamp = last = max(out_s + (j / 60.0 - k / FPS), last + 1e-6)
            tx.sendto(_pose_bytes(stamp, (*pos, *q)), address)
            sent.append((*pos, *q))
            j += 1
        if k == 10:
            for data in bad:
                tx.sendto(data, address)
        k += 1
    tx.close()
    return sent


def test_live_session_with_streamed_poses_logs_them_and_replays(tmp_path):
    sensor_path = SAMPLES / "nominal.sensor.toml"
    calib_path = SPACE / "calib.toml"
    out, avi = tmp_path / "live.csv", tmp_path / "session.avi"
    mount_text = "0,0,-40,0.9659258,0,0,0.2588190"
    cap = PlaybackSource(CLIP, FPS)
    stdout = io.StringIO()
    config = LiveConfig(mode="every", record=avi, jsonl=True, controls=False,
                        calib=read_calibration(calib_path), calib_path=str(calib_path),
                        eta_deg=0.5, base_port=0, base_poses=True,
                        mount=Mount.parse(mount_text), handle_signals=False,
                        springs=suspension_stiffness())  # as the command with --calib  # fmt: skip
    session = LiveSession(cap, load_sensor(sensor_path), out, config, stdout)
    bad = [b'{"t_s": 1, "x_mm": 2}', _pose_bytes(1e9, (0, 0, 0, 0.5, 0, 0, 0)),
           b'{"t_s": 1e9, "x_mm": 0, "y_mm": NaN, "z_mm": 0, "qw": 1, "qx": 0, "qy": 0, '
           b'"qz": 0}']  # fmt: skip
    result: list = []
    sender = threading.Thread(target=lambda: result.extend(
        _send_poses(cap, session.base.address, 20.0, bad)), daemon=True)
    sender.start()
    rep = session.run()
    sender.join()
    assert rep.rows == 90
    contact = json.loads(out.with_suffix(".json").read_text())["contact"]
    meta = contact["base"]
    # A carrier that keeps its orientation: no turn (float rounding), no problem said.
    assert contact["base_turn_deg"] <= 1e-5 and not any("turned" in p for p in rep.problems)
    # Every good pose sent while the clip played came (the last few may be sent after the
    # session stopped receiving), and the three bad ones were named.
    n = meta["received"]
    assert meta["kind"] == "poses" and len(result) - 3 <= n <= len(result) and n >= 170
    assert meta["rejected"] == {
        "a position {t_s, x_mm} where poses are expected": 1,
        f"keys qw-qz: the quaternion's norm is not 1 within {QUAT_NORM_TOL:g}": 1,
        "key y_mm: missing or not a finite number": 1}
    # The pose log: section 9's, on the camera clock, the poses exactly as sent (repr).
    log_path = pose_log_path(out)
    assert meta["log"] == str(log_path)
    samples = read_pose_log_samples(log_path)
    assert [s[1] for s in samples] == result[:n]
    assert read_pose_log(log_path).t_s.size == n
    rows = list(csv.DictReader(io.StringIO(out.read_text())))
    assert list(rows[0])[-6:] == list(WORLD_COLUMNS)
    placed = [r for r in rows if r["px_mm"]]
    assert len(placed) >= 10  # the clip's contacts get points
    # A normal is a unit vector across the shaft (its cells at 1e-6).
    for r in placed:
        assert math.hypot(*(float(r[k]) for k in ("nx", "ny", "nz"))) == pytest.approx(1, abs=3e-6)
    messages = [json.loads(line) for line in stdout.getvalue().splitlines()]
    for m, r in zip(messages, rows, strict=True):
        for key in WORLD_COLUMNS:
            assert (m[key] is None and r[key] == "") or m[key] == float(r[key])
    # Replay with the session's pose log and mount: the live table again, byte for byte.
    again = tmp_path / "again.csv"
    code = main(["replay", str(avi), "--out", str(again), "--sensor", str(sensor_path),
                 "--calib", str(calib_path), "--eta-deg", "0.5", "--pose-log", str(log_path),
                 "--mount", mount_text])  # fmt: skip
    assert code == 0
    assert again.read_bytes() == out.read_bytes()


def test_pose_options_are_checked(tmp_path, capsys):
    calib = str(SPACE / "calib.toml")
    out = str(tmp_path / "o.csv")
    assert main(["live", "x.avi", "--out", out, "--calib", calib, "--base-poses"]) == 2
    assert "--base-poses goes with --base-udp" in capsys.readouterr().err
    mount = ["--mount", "0,0,0,1,0,0,0"]
    assert main(["replay", "x.avi", "--out", out, "--calib", calib, *mount]) == 2
    assert "--mount goes with base poses (--pose-log)" in capsys.readouterr().err
    bad = tmp_path / "bad.pose.csv"
    bad.write_text("t_s,x_mm,y_mm,z_mm,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n1,0,0,0,2,0,0,0\n")
    assert main(["replay", "x.avi", "--out", out, "--calib", calib, "--pose-log", str(bad)]) == 2
    assert f"{bad}: row 3, columns qw-qz: the quaternion's norm is 2" in capsys.readouterr().err
    assert not (tmp_path / "o.csv").exists()


def test_the_view_draws_the_contact_points_as_they_come():
    """The view's page (headless Chromium, as tests/test_view.py) shows the points panels
    once rows with a contact point come, holding every point published (its count)."""
    from camwhisker.bench.view import headless_chromium, quit_chromium
    from camwhisker.live.view import LiveView
    from camwhisker.sensor.model import PlateModel
    from camwhisker.vision.stream import Frame
    from camwhisker.vision.tracker import FrameResult

    view = LiveView(PlateModel(load_sensor(SAMPLES / "nominal.sensor.toml")), lambda name: None)
    view.start()
    driver = headless_chromium()
    try:
        driver.get(view.url)
        js = driver.execute_script
        hidden = "return document.getElementById('points-top').hidden"
        assert js(hidden) is True  # no point yet: no panel
        for i in range(40):
            # The first 10 rows have no point (no contact): they are not drawn.
            point = dict(zip(WORLD_COLUMNS[:3], (100.0 + i, -5.0 + 0.1 * i, 300.0 - i),
                             strict=True)) if i >= 10 else dict.fromkeys(WORLD_COLUMNS[:3])
            view.publish(Frame(i, i / FPS, None), FrameResult.untrusted(i, "test"), 1.0, 0,
                         None, {"contact_b": 1.0, "r_hat_mm": 50.0, "z_score": 0.0, **point})
            time.sleep(0.01)
        deadline = time.monotonic() + 60.0
        count = "return document.getElementById('points-side').dataset.points"
        while js(count) != "30" and time.monotonic() < deadline:
            time.sleep(0.1)
        assert js(count) == "30" and js(hidden) is False
        assert js("return window.view.points[29]") == [139.0, -1.1, 261.0]  # the last, i = 39
    finally:
        quit_chromium(driver)
        view.close()
