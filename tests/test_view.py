"""The live view (``camwhisker live --view``): the page in headless Chromium, the endpoints.

The session plays the bundled nominal clip (1280 x 720, 90 frames, looped) at
30 frames/s through the playback capture, as tests/test_live.py does. Nothing
asserts a wall-clock time: waits are bounded (``WAIT_S``) only so that a broken
page fails instead of hanging, and what is asserted are counts, frame indices
and table cells. Chromium and its driver are Debian's (README's test command
installs them).
"""

from __future__ import annotations

import csv
import json
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from camwhisker.bench.view import headless_chromium, quit_chromium
from camwhisker.io.sources import read_timestamps, timestamps_path
from camwhisker.live.loop import LiveConfig, LiveSession
from camwhisker.live.playback import PlaybackSource
from camwhisker.live.view import CLIENT_IDLE_S, VIEW_WIDTH_PX
from camwhisker.sensor.file import load_sensor

# Plays video at camera rate or times a live loop: run alone (README's test command).
pytestmark = pytest.mark.timing

SAMPLES = Path(__file__).resolve().parents[1] / "sample_frames"
CLIP = SAMPLES / "nominal.mp4"
#: Bound on every wait for the page or the session (s): a guard, not a measurement.
WAIT_S = 60.0


@pytest.fixture(scope="module")
def sensor():
    return load_sensor(SAMPLES / "nominal.sensor.toml")


def _until(check, what: str):
    """Poll ``check()`` until it is truthy (returned) or WAIT_S passes (fails, naming what)."""
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        value = check()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"not within {WAIT_S:g} s: {what}")


class Running:
    """A live session on its own thread, played at 30 frames/s, looped."""

    def __init__(self, sensor, out: Path, **config):
        cap = PlaybackSource(CLIP, 30.0, loop=True)
        self.session = LiveSession(cap, sensor, out, LiveConfig(controls=False, view_port=0,
                                                                handle_signals=False, **config))
        self.report = None
        self.error = None
        self.thread = threading.Thread(target=self._run)
        self.thread.start()

    def _run(self):
        try:
            self.report = self.session.run()
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            self.error = exc

    def finish(self):
        self.session.stop("quit")
        self.thread.join()
        if self.error is not None:
            raise self.error
        return self.report


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _event(session, name, after=-1):
    """The frame of the first ``name`` event after frame ``after`` in the session's report."""
    hits = [e["frame"] for e in session.report.events if e["event"] == name and e["frame"] > after]
    return hits[0] if hits else None


def test_page_in_chromium_follows_the_loop_and_its_buttons_land_in_the_table(tmp_path, sensor):
    out, avi = tmp_path / "live.csv", tmp_path / "s.avi"
    run = Running(sensor, out, record=avi, duration_s=10 * WAIT_S)
    try:
        _check_page_and_buttons(run, out, avi)
    finally:  # a failed check does not leave the session running
        run.session.stop("test ended")
        run.thread.join()


def _check_page_and_buttons(run, out, avi):
    session = run.session
    driver = headless_chromium()
    try:
        driver.get(session.view.url)
        js = driver.execute_script
        assert driver.title == "camwhisker live"
        # The picture and the plots update while the clip plays.
        _until(lambda: js("return window.view.pictures") >= 3, "three pictures")
        first = int(js("return document.getElementById('frame').dataset.frame"))
        # The header names the picture's own frame; a panel shows only where it has data
        # (no --calib here: no belief, r or Z panel).
        _until(lambda: js("return document.getElementById('picture-index').textContent")
               == js("return document.getElementById('frame').dataset.frame"), "the header")
        assert js("return document.getElementById('plot-phi').hidden") is False
        assert js("return ['plot-belief', 'plot-r', 'plot-z'].map("
                  "(id) => document.getElementById(id).hidden)") == [True, True, True]
        plot_before = js("return document.getElementById('plot-phi').toDataURL()")
        plotted_before = int(js("return document.getElementById('plot-phi').dataset.lastFrame"))
        _until(lambda: int(js("return document.getElementById('frame').dataset.frame"))
               >= first + 30, "a picture 30 rows later")  # fmt: skip
        _until(lambda: int(js("return document.getElementById('plot-phi').dataset.lastFrame"))
               >= plotted_before + 30, "plots 30 rows later")  # fmt: skip
        assert js("return document.getElementById('plot-phi').toDataURL()") != plot_before
        # The picture is the whole camera frame (1280 x 720), scaled to the page's width.
        size = js("const f = document.getElementById('frame'); "
                  "return [f.naturalWidth, f.naturalHeight]")  # fmt: skip
        assert size == [VIEW_WIDTH_PX, round(720 * VIEW_WIDTH_PX / 1280)]
        # The page has every row since it opened, in order: no row lost on the way.
        frames = js("return window.view.rows.map((r) => r[0])")
        assert len(frames) >= 30 and frames == list(range(frames[0], frames[-1] + 1))

        # A click on re-zero is the re-zero event: in the sidecar's events, and in the table
        # (at rest it reads zero exactly; deflected, the re-zero is refused and says so).
        driver.find_element("id", "rezero").click()
        k = _until(lambda: _event(session, "rezero"), "the re-zero event")
        _until(lambda: len(_rows(out)) > k, "the re-zero row in the table")
        row = _rows(out)[k]
        assert (row["phi_deg"], row["ok"]) == ("0.00000", "1") or (
            row["ok"] == "0" and row["note"].startswith("re-zero failed")
        )
        assert [e["event"] for e in session.report.events] == ["rezero"]  # one click, one event
        _until(lambda: js("return document.getElementById('message').textContent")
               == "rezero sent", "the page's acknowledgement")  # fmt: skip

        # Stop and start recording: the rows between are not in the recording.
        driver.find_element("id", "record").click()
        stop = _until(lambda: _event(session, "record-stop"), "record-stop")
        _until(lambda: js("return document.getElementById('record').textContent")
               == "start recording", "the button to say start")  # fmt: skip
        driver.find_element("id", "record").click()
        start = _until(lambda: _event(session, "record-start", stop), "record-start")
        assert start > stop
    finally:
        quit_chromium(driver)
    # The page closed: the loop goes on, and the view stops drawing once no page asks.
    closed_at = session.report.rows
    _until(lambda: session.report.rows >= closed_at + 60, "60 rows after the page closed")
    t_close = float(_rows(out)[closed_at]["t_s"])
    idle_s = CLIENT_IDLE_S + 0.5  # the frame grabbed before the close, with a margin
    _until(lambda: float(_rows(out)[-1]["t_s"]) > t_close + idle_s, "the view to go idle")
    pictures = session.view.pictures
    rows_idle = session.report.rows
    _until(lambda: session.report.rows >= rows_idle + 30, "30 more rows")
    assert session.view.pictures == pictures
    rep = run.finish()
    assert rep.stopped_by == "quit" and not rep.failed
    stamps = [s["frame"] for s in read_timestamps(timestamps_path(avi))]
    assert stamps == list(range(stop)) + list(range(start, rep.rows))
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["recording"]["frames"] == len(stamps)
    assert [e["event"] for e in meta["events"]] == ["rezero", "record-stop", "record-start"]
    assert meta["view"]["pictures"] == pictures


def _request(url, method="GET", origin=None):
    headers = {"Origin": origin} if origin else {}
    try:
        with urllib.request.urlopen(urllib.request.Request(url, headers=headers,
                                                           method=method)) as r:  # fmt: skip
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


def test_endpoints_without_a_browser(tmp_path, sensor):
    """No --record: the record command is refused (409) and nothing is recorded; an unknown
    command or page is 404; the state lists the rows with their numbers."""
    run = Running(sensor, tmp_path / "live.csv", duration_s=WAIT_S)
    url = run.session.view.url
    try:
        _until(lambda: run.session.report.rows >= 10, "10 rows")
        status, body = _request(url + "command/record", "POST", url.rstrip("/"))
        assert status == 409 and "--record" in json.loads(body)["error"]
        # The page cannot end a session.
        assert _request(url + "command/quit", "POST", url.rstrip("/"))[0] == 404
        assert _request(url + "nothing")[0] == 404
        # The view takes the rows on its own thread: wait for the tenth there too.
        state = _until(lambda: (s := json.loads(_request(url + "state?after=-1")[1]))["rows"][9:]
                       and s, "10 rows in the state")  # fmt: skip
        assert state["recording"] is None and state["events"] == []
        frames = [r[0] for r in state["rows"]]
        assert frames[:10] == list(range(10))
        # frame, t_s, dz, phi, theta, ok, ms, then belief, r, Z: none without --calib
        assert all(len(r) == 10 and r[7:] == [None] * 3 for r in state["rows"])
    finally:
        rep = run.finish()
    assert rep.events == [] and rep.stopped_by == "quit"


def test_a_taken_port_is_an_error_that_writes_nothing(tmp_path, sensor):
    run = Running(sensor, tmp_path / "a.csv", duration_s=WAIT_S)
    port = run.session.view.port
    try:
        with pytest.raises(OSError, match=f"--view 127.0.0.1:{port}"):
            LiveSession(PlaybackSource(CLIP, 30.0), sensor, tmp_path / "b.csv",
                        LiveConfig(controls=False, view_port=port))  # fmt: skip
    finally:
        run.finish()
    assert not (tmp_path / "b.csv").exists()


def test_state_figures_from_published_rows():
    """Rows handed over as the loop does: the state has each once, in order, with the frame
    rate from their times and the latency percentiles of the last STATS_ROWS."""
    from camwhisker.io.sources import Frame
    from camwhisker.live.view import STATS_ROWS, LiveView
    from camwhisker.sensor.model import PlateModel
    from camwhisker.vision.tracker import FrameResult

    commands = []
    view = LiveView(PlateModel(load_sensor(SAMPLES / "nominal.sensor.toml")), commands.append)
    view.start()
    try:
        n = 2 * STATS_ROWS
        for i in range(n):  # 25 frames/s; latency i ms
            view.publish(Frame(i, i / 25.0, None, ""), FrameResult.untrusted(i, "test"), float(i),
                         dropped=i // 10)  # fmt: skip
        state = _until(lambda: (s := view.state_after(n - 2))["rows"] and s, "the last row")
        assert [r[0] for r in state["rows"]] == [n - 1]
        assert state["fps"] == 25.0  # (STATS_ROWS - 1) frames over (STATS_ROWS - 1) / 25 s
        recent = np.arange(n - STATS_ROWS, n, dtype=float)
        assert state["latency_p50_ms"] == pytest.approx(np.percentile(recent, 50), abs=0.005)
        assert state["latency_p99_ms"] == pytest.approx(np.percentile(recent, 99), abs=0.005)
        assert state["dropped"] == (n - 1) // 10 and state["recording"] is None
        assert [r[0] for r in view.state_after(-1)["rows"]] == list(range(n))
        assert view.pictures == 0  # no page asked for one
        status, _ = _request(view.url + "command/rezero", "POST")
        assert status == 403 and commands == []  # no Origin: not from the view's page
        status, _ = _request(view.url + "command/rezero", "POST", view.url.rstrip("/"))
        assert status == 200 and commands == ["rezero"]
    finally:
        view.close()


def test_contact_fields_reach_the_plots_columns():
    """With live --calib a row carries its contact fields: the state's rows end with the
    belief, r (the fused one where given, else MF's) and Z, rounded to 4 digits, and
    None where a field is empty or the session computes no contact."""
    from camwhisker.live.view import Published, _row_numbers
    from camwhisker.vision.tracker import FrameResult

    r = FrameResult.untrusted(3, "test")
    fused = {"contact_b": 0.51234, "r_mf_mm": 88.2, "r_hat_mm": 90.123456, "z_score": -1.23456}
    mf_only = {"contact_b": 1.0, "r_mf_mm": 70.0000449, "sigma_mf_mm": 2.0}
    empty = {"contact_b": None, "r_mf_mm": None, "z_score": None}
    tails = [_row_numbers(Published(3, 0.1, "", r, 1.0, 0, None, c))[7:]
             for c in (fused, mf_only, empty, None)]
    assert tails == [[0.5123, 90.1235, -1.2346], [1.0, 70.0, None], [None, None, None],
                     [None, None, None]]


def test_bench_text_compares_each_open_session_with_the_closed_one_before():
    from camwhisker.bench.view import text

    def arm(p99, sessions):
        summary = {"p50_ms": 1.0, "p99_ms": p99, "max_ms": 9.0, "n": 100}
        return {"processing": summary, "end_to_end": summary, "session_p99_ms": sessions,
                "pictures": 0}  # fmt: skip

    out = text({"closed": arm(4.0, [4.0, 5.0]), "open": arm(4.2, [4.4, 4.5])}, 4, 100)
    assert "processing p99 rise with the view open: +5.0 %" in out  # 4.2 / 4.0
    assert "median 1.00, range 0.90-1.10" in out  # 4.4 / 4.0 and 4.5 / 5.0
