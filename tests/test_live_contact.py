"""Contact live (issue #22 item 5): the belief, MF, GM, Z, fusion and eq. 12 per live row.

The end-to-end test plays a simulated mapping run (a rigid peg swept at 5 mm/s
without pauses, rendered as webcam video) at camera rate while a sender thread
streams the base positions on loopback UDP, and holds the live rows to the
batch commands run on the live table and the base log the session wrote:

- the belief equals ``camwhisker belief``'s on every row after the rest frames;
- x: the base log interpolated, but past the newest position live extrapolates
  (hundredths of a mm: the sender's stamps carry the playback's jitter); the rest
  is compared given the positions live used (a stage log of the rows' x);
- GM agrees within a quarter of its own spread (sigma_GM)
  once live has fixed the onset (phi past 5 deg: batch uses the same frames) and
  away from the base's start and stop; within 3 sigma_GM before that (live's onset
  comes from the frames so far) and within one smoothing window of the kinks (the
  centred window, batch, and the trailing one, live, straddle them differently);
- the fused estimate agrees as GM where both keep GM; elsewhere the bias
  corrections differ by design (batch's borrows later frames, live's cannot);
- MF agrees within 2 sigma_MF: dz grows as phi^2, so the line through the
  later frames (batch) and the earlier ones (live) differ by their curvature
  bias, and MF reads r from small dz differences;
- replay reproduces the live table byte for byte.
"""

from __future__ import annotations

import csv
import io
import json
import math
import socket
import threading
import time

import numpy as np
import pytest

from camwhisker.cli.parser import main
from camwhisker.contact.belief import find_onsets
from camwhisker.contact.belief_table import table_belief
from camwhisker.contact.calibrate import read_calibration, write_calibration
from camwhisker.contact.fusion import KEEP_GM_POSTERIOR, OnlineFusion, fuse
from camwhisker.contact.online import MAX_EXTRAPOLATE_S, BaseFeed, BaseTrack, OnlineContact
from camwhisker.contact.pipeline import contact_rows, smooth_half_frames
from camwhisker.contact.stage import (
    ONSET_PHI_MAX_DEG,
    Pauses,
    pause_index,
    read_stage_log,
    stage_log_from_arrays,
)
from camwhisker.io.signals import read_signal_table
from camwhisker.live.base import BaseReceiver, base_log_path, parse_base_datagram
from camwhisker.live.loop import LiveConfig, LiveSession
from camwhisker.live.playback import PlaybackSource
from camwhisker.sensor.file import Sensor
from camwhisker.sensor.springs import suspension_stiffness
from camwhisker.sim.mechanics.experiment import continuous_protocol, simulate_runs
from camwhisker.sim.render.experiment import pose_track
from camwhisker.sim.render.scenarios import NOMINAL_ARTEFACTS, Scenario
from camwhisker.sim.render.video import render_scenario
from tests.test_calibrate import calibration

# Plays video at camera rate or times a live loop: run alone (README's test command).
pytestmark = pytest.mark.timing

FPS = 30.0
#: The mapping run: the issue's top base speed, a short sweep (tuning seed 5).
SPEED_MM_S = 5.0
RUN_SEED = 5


def _run():
    # 0.6 s at rest at each end: the rest reference (30 frames) still fits before contact.
    protocol = continuous_protocol(SPEED_MM_S, rest_s=0.6, phi_stop_deg=15.0)
    return simulate_runs("rigid", RUN_SEED, protocol=protocol)[0]


def test_online_fusion_is_fuse_at_the_newest_sample():
    rng = np.random.default_rng(1)
    r_gm = 30.0 + rng.normal(0, 0.5, 40)
    r_mf = 27.0 + rng.normal(0, 3.0, 40)
    r_mf[:5] = np.nan  # MF undefined at small phi: weight 0, the decay goes on
    s_gm, s_mf = np.full(40, 0.6), np.full(40, 2.5)
    online = OnlineFusion()
    for i in range(40):
        got = online(r_gm[i:i + 1], r_mf[i:i + 1], s_gm[i:i + 1], s_mf[i:i + 1], 150.0)
        want = fuse(r_gm[:i + 1], r_mf[:i + 1], s_gm[:i + 1], s_mf[:i + 1], 150.0)
        # The forward recursion is the two-sided sums' last sample: float rounding only.
        for g, w in zip(got, want, strict=True):
            np.testing.assert_allclose(g[0], w[-1], rtol=1e-12, atol=1e-12, equal_nan=True)


def test_base_track_interpolates_then_extrapolates_then_gives_up():
    track = BaseTrack()
    for t, x in ((0.0, 0.0), (0.1, 0.5), (0.2, 0.5)):
        assert track.add(t, x)
    assert not track.add(0.2, 9.0)  # not after the last one: refused
    assert math.isnan(track.at(-0.01)[0])  # before the first sample
    assert track.at(0.05) == pytest.approx((0.25, 5.0), abs=1e-12)  # 5 mm/s segment
    assert track.at(0.15) == pytest.approx((0.5, 0.0), abs=1e-12)
    track.add(0.3, 1.0)
    assert track.at(0.35) == pytest.approx((1.25, 5.0), abs=1e-12)  # past the newest
    assert math.isnan(track.at(0.3 + MAX_EXTRAPOLATE_S + 1e-6)[0])  # stale: no x
    assert track.travel_sign == 1.0
    feed = BaseFeed(BaseTrack())
    for t, rcv in ((0.0, 0.01), (0.1, 0.11), (0.05, 0.12)):
        feed.put(t, 1.0, rcv)
    feed.advance(0.1)
    assert feed.track.t_s == [0.0]  # the second arrived after the frame
    feed.advance(1.0)
    assert feed.track.t_s == [0.0, 0.1] and feed.out_of_order == 1


def test_a_base_log_without_pauses_puts_no_frame_in_a_pause():
    # A short live session's base log may never stand still for a pause (>= 1 s).
    none = Pauses(np.array([]), np.array([]), np.array([]))
    assert pause_index([0.0, 1.0, np.nan], none, 0.0, 0.1).tolist() == [-1, -1, -1]


def test_base_datagrams_bad_ones_are_counted_not_fatal():
    assert parse_base_datagram(b'{"t_s": 1.5, "x_mm": -2, "v": 3}') == (1.5, -2.0)
    for bad, why in ((b"\xff", "not JSON"), (b"[1, 2]", "not a JSON object"),
                     (b'{"t_s": 1}', "key x_mm"), (b'{"t_s": NaN, "x_mm": 1}', "key t_s"),
                     (b'{"t_s": true, "x_mm": 1}', "key t_s")):
        with pytest.raises(ValueError, match=why):
            parse_base_datagram(bad)
    rx = BaseReceiver(0)
    rx.start()
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for data in (b'{"t_s": 1, "x_mm": 0}', b"junk", b'{"t_s": 1, "x_mm": 1}',
                 b'{"t_s": 2, "x_mm": 1}'):
        tx.sendto(data, rx.address)
    deadline = time.monotonic() + 10.0
    while rx.received + sum(rx.rejected.values()) < 4 and time.monotonic() < deadline:
        time.sleep(0.01)
    rx.stop()
    tx.close()
    assert [s[:2] for s in rx.take()] == [(1.0, 0.0), (2.0, 1.0)]
    assert rx.rejected == {"not JSON": 1, "t_s not after the previous position's": 1}


def test_online_contact_on_simulated_signals_matches_the_batch_commands():
    """No video: the simulator's signals (paper noise) with every base position known."""
    calib = calibration()
    run = _run()
    s = run.signals
    ok = s["ok"].astype(bool)
    log = stage_log_from_arrays(run.stage["t_s"] + run.offset_s, run.stage["x_mm"])
    batch, analysis = contact_rows({**s, "ok": ok}, log, calib, 0.0)
    track = BaseTrack()
    for t, x in zip(log.t_s, log.x_mm, strict=True):
        track.add(t, x)
    online = OnlineContact(calib, 1 / FPS, base=track)
    rest = (0, 30)
    rows = [online.update(i, s["t_s"][i], s["phi_deg"][i], s["dz_mm"][i], ok[i],
                          rest if i >= 29 else None) for i in range(ok.size)]
    col = {k: np.array([r[k] for r in rows]) for k in ("contact_b", "contact", "dx_mm", "x_mm")}
    d = np.where(ok, s["phi_deg"], np.nan)
    b, flag, _ = find_onsets(d, online.eta_deg)
    # The belief: eq. 1 with the same eta, frame by frame (float rounding only).
    np.testing.assert_allclose(col["contact_b"][30:], b[30:], atol=1e-12)
    assert np.array_equal(col["contact"][30:], flag[30:].astype(int))
    np.testing.assert_allclose(col["x_mm"], batch["x_mm"], atol=1e-9)  # interpolated alike
    # Once phi passes ONSET_PHI_MAX_DEG the onset is fixed from the same frames: the same.
    late = np.flatnonzero(np.nan_to_num(s["phi_deg"]) >= ONSET_PHI_MAX_DEG)[0]
    np.testing.assert_allclose(col["dx_mm"][late:], batch["dx_mm"][late:], atol=1e-9)
    assert math.isfinite(analysis.x_contact_mm)
    assert online.half_frames == smooth_half_frames(1 / FPS) == 6


def _send_base(cap: PlaybackSource, address, t_s, x_mm) -> None:
    """The robot: each base position (t_s on the video's clock) sent with a stamp on this
    machine's monotonic clock. It paces itself by the frames the playback has released,
    not by the clock alone: on a loaded machine the playback falls behind the clock, and
    a base streamed by the clock would run ahead of the video. The positions of frame
    k's period are sent once frame k is out, stamped from the moment it came out."""
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    j, k = 0, 0
    while j < len(t_s):
        if cap.released <= k:
            if cap.ended:
                break
            time.sleep(0.0005)
            continue
        out_s = time.monotonic()  # frame k (on the video's clock k / FPS) just came out
        while j < len(t_s) and t_s[j] < (k + 1) / FPS:
            stamp = out_s + (t_s[j] - k / FPS)
            tx.sendto(json.dumps({"t_s": stamp, "x_mm": float(x_mm[j])}).encode(), address)
            j += 1
        k += 1
    tx.close()


def _column(rows, name):
    return np.array([float(r[name]) if r[name] else np.nan for r in rows])


def _agrees_with_the_contact_command(out, rows, run, calib) -> None:
    """The live rows against the contact command (see the module's docstring)."""
    n = len(rows)
    base_log = base_log_path(out)
    # The contact command on the live table and the base log the session wrote.
    signals = read_signal_table(out)
    live = {k: _column(rows, k) for k in ("x_mm", "dx_mm", "r_gm_mm", "r_hat_mm", "r_mf_mm")}
    # x: the base log's positions interpolated to the frame time; past the newest one live
    # extrapolates along the last segment, whose slope carries the stamps' jitter (the
    # sender paces itself by the playback): hundredths of a mm typically, and at most the
    # extrapolation's reach at the base's top speed.
    dx_base = np.abs(live["x_mm"] - read_stage_log(base_log).x_at(signals["t_s"]))
    both = np.isfinite(dx_base)
    assert both.sum() >= n - 2
    assert np.median(dx_base[both]) <= 0.01
    assert dx_base[both].max() <= SPEED_MM_S * MAX_EXTRAPOLATE_S
    # The contact command given the positions live used (a stage log of the rows' t_s and
    # x_mm): what is left are the differences of seeing no later frame.
    has_x = np.isfinite(live["x_mm"])
    used = stage_log_from_arrays(signals["t_s"][has_x], live["x_mm"][has_x])
    batch, _ = contact_rows(signals, used, calib, 0.0)
    # dx: once live has fixed the onset (phi past ONSET_PHI_MAX_DEG), from the same frames
    # and positions as batch: the same, to the x cells' rounding (0.1 um).
    phi = signals["phi_deg"]
    late = phi >= ONSET_PHI_MAX_DEG
    assert np.nanmax(np.abs(live["dx_mm"] - batch["dx_mm"])[late]) <= 1e-3
    # GM, rows at phi >= 2 deg without doubt, in units of sigma_GM: within a quarter of it
    # once the onset is fixed and away from the base's kinks (what is left: the two
    # windows' noise); within 3 sigma_GM before (live's onset comes from the frames so far)
    # and near them (the centred window, batch, and the trailing one, live, straddle them
    # differently).
    half = smooth_half_frames(1 / FPS)
    t = batch["t_s"]
    # The base's starts and stops: where the schedule's speed changes (camera clock).
    speed = np.diff(run.schedule_x_mm) / np.diff(run.schedule_t_s)
    kinks = run.schedule_t_s[1:-1][np.abs(np.diff(speed)) > 1e-9]
    assert kinks.size == 2
    near = np.min(np.abs(t[:, None] - kinks[None, :]), axis=1) <= (half + 1) / FPS
    near |= np.arange(n) < np.argmax(late)  # the onset not fixed yet
    sel = (phi >= 2.0) & (batch["doubt"] == "") & np.isfinite(batch["r_gm_mm"])
    assert sel.sum() >= 0.4 * n
    q = np.abs(live["r_gm_mm"] - batch["r_gm_mm"]) / batch["sigma_gm_mm"]
    assert np.all(np.isfinite(q[sel]))
    assert (sel & ~near).sum() >= 0.2 * n
    assert q[sel & ~near].max() <= 0.25
    assert q[sel & near].max() <= 3.0
    # The fusion: where both keep GM (P(GM good) >= KEEP_GM_POSTERIOR), as GM. Elsewhere
    # they differ by their bias corrections, which differ by design: batch's bias estimate
    # borrows the later frames too, live's has only the earlier ones.
    p_live = _column(rows, "p_gm_good")
    keep = sel & ~near & (p_live >= KEEP_GM_POSTERIOR) & (batch["p_gm_good"] >= KEEP_GM_POSTERIOR)
    assert keep.sum() >= 0.1 * n
    q = np.abs(live["r_hat_mm"] - batch["r_hat_mm"]) / batch["sigma_gm_mm"]
    assert q[keep].max() <= 0.25
    q = np.abs(live["r_mf_mm"] - batch["r_mf_mm"]) / batch["sigma_mf_mm"]
    assert np.nanmedian(q[sel]) <= 0.1 and np.nanmax(q[sel]) <= 2.0


def test_live_contact_on_a_rendered_mapping_run_agrees_with_batch(tmp_path):
    run = _run()
    video = tmp_path / "map.avi"
    render_scenario(Scenario("map", "mapping run", pose_track(run), NOMINAL_ARTEFACTS,
                             FPS), Sensor(), video, seed=7)
    calib_path = tmp_path / "calib.toml"
    write_calibration(calib_path, calibration())
    calib = read_calibration(calib_path)  # as the commands read it (the MF table as written)
    out, avi = tmp_path / "live.csv", tmp_path / "session.avi"
    cap = PlaybackSource(video, FPS)
    stdout = io.StringIO()
    config = LiveConfig(mode="every", record=avi, jsonl=True, controls=False, calib=calib,
                        calib_path=str(calib_path), base_port=0,
                        springs=suspension_stiffness())  # as the command with --calib
    session = LiveSession(cap, Sensor(), out, config, stdout)
    # Stage time -> the video's time (camera time = true time = stage time + offset).
    sender = threading.Thread(target=_send_base, daemon=True, args=(
        cap, session.base.address, run.stage["t_s"] + run.offset_s, run.stage["x_mm"]))
    sender.start()
    rep = session.run()
    sender.join()
    n = run.truth["t_s"].size
    assert rep.rows == n and rep.rows_ok == n
    rows = list(csv.DictReader(io.StringIO(out.read_text())))
    meta = json.loads(out.with_suffix(".json").read_text())
    base_log = base_log_path(out)
    # Every position up to the last frame came (the stage log runs on 1 s past the video).
    sent_in_time = np.sum(run.stage["t_s"] + run.offset_s < run.truth["t_s"][-1])
    assert meta["contact"]["base"]["received"] >= sent_in_time
    assert meta["contact"]["base"]["rejected"] == {}

    # Messages carry the row's fields, rounded alike.
    messages = [json.loads(line) for line in stdout.getvalue().splitlines()]
    for m, r in zip(messages, rows, strict=True):
        for key in ("contact_b", "r_mf_mm", "x_mm", "r_gm_mm", "r_hat_mm", "z_score"):
            assert (m[key] is None) == (r[key] == "")
            if m[key] is not None:
                assert m[key] == float(r[key])
        assert m["doubt"] == r["doubt"] and m["contact"] == int(r["contact"])

    # The belief command on the live table: the same eta, belief and flag after the rest
    # frames (live has no belief on them: eta comes from them).
    belief = table_belief(out)
    assert meta["contact"]["eta_deg"] == belief.eta_deg
    rest_end = belief.rest_rows[-1] + 1
    assert all(r["contact_b"] == "" for r in rows[:rest_end])
    assert [r["contact_b"] for r in rows[rest_end:]] == [f"{b:.4f}" for b in belief.b[rest_end:]]
    assert _column(rows, "contact").astype(bool).tolist() == belief.flag.tolist()
    assert belief.flag.sum() > 0.4 * n  # the run does make contact

    _agrees_with_the_contact_command(out, rows, run, calib)

    # Replay with the base log: the live table again, byte for byte.
    again = tmp_path / "again.csv"
    code = main(["replay", str(avi), "--out", str(again), "--calib", str(calib_path),
                 "--base-log", str(base_log)])
    assert code == 0
    assert again.read_bytes() == out.read_bytes()


def test_contact_options_need_a_calibration(tmp_path, capsys):
    assert main(["live", "x.avi", "--out", str(tmp_path / "o.csv"), "--base-udp", "0"]) == 2
    assert "need --calib" in capsys.readouterr().err
    calib_path = tmp_path / "calib.toml"
    write_calibration(calib_path, calibration())
    missing = tmp_path / "none.base.csv"
    assert main(["replay", "x.avi", "--out", str(tmp_path / "o.csv"), "--calib",
                 str(calib_path), "--base-log", str(missing)]) == 2
    assert str(missing) in capsys.readouterr().err
    assert not (tmp_path / "o.csv").exists()
