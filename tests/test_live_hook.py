"""The closed-loop hook: a live session's rows handed to Python (``on_row``, ``cw.live_rows``).

The bundled 12-frame MJPG clip (30 fps) plays at camera rate in "every" mode, so every
frame gives a row at any machine speed; nothing asserts a wall-clock time except the stop
after a ``break``, with a bound (1 s) ten times the loop's poll interval.
"""

from __future__ import annotations

import csv
import json
import time
from pathlib import Path

import pytest

import camwhisker as cw
from camwhisker.live.loop import LiveConfig, LiveSession, RowCallbackError
from camwhisker.live.playback import PlaybackSource
from camwhisker.sensor.file import load_sensor

# Plays video at camera rate: run alone (README's test command).
pytestmark = pytest.mark.timing

SAMPLES = Path(__file__).resolve().parents[1] / "sample_frames"
MJPG = SAMPLES / "nominal_mjpg.avi"  # 12 frames, 30 fps
MJPG_FRAMES = 12
CLIP = SAMPLES / "nominal.mp4"  # 90 frames, 30 fps: 3 s, long enough to break out of
#: phi_deg is written with 5 decimals: a row and its dict agree to half the last digit.
PHI_TOL = 0.5e-5
SLEEP_S = 0.002


@pytest.fixture(scope="module")
def sensor():
    return load_sensor(SAMPLES / "nominal_mjpg.sensor.toml")


def _table(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_on_row_gets_each_row_of_the_table_and_its_time_is_measured(tmp_path, sensor):
    got = []

    def hook(row):
        got.append(row)
        time.sleep(SLEEP_S)  # a known cost the measurement must see

    out = tmp_path / "live.csv"
    rep = LiveSession(PlaybackSource(MJPG, 30.0), sensor, out,
                      LiveConfig(mode="every", controls=False, on_row=hook)).run()  # fmt: skip
    table = _table(out)
    assert len(got) == len(table) == rep.rows == MJPG_FRAMES
    assert [g["frame"] for g in got] == [int(r["frame"]) for r in table] == list(range(12))
    assert [g["t_s"] for g in got] == [float(r["t_s"]) for r in table]  # exact: same rounding
    for g, r in zip(got, table, strict=True):
        assert type(g["frame"]) is int and type(g["ok"]) is int and g["ok"] == int(r["ok"])
        if r["phi_deg"]:
            assert abs(g["phi_deg"] - float(r["phi_deg"])) <= PHI_TOL
        else:
            assert g["phi_deg"] is None
        assert isinstance(g["latency_ms"], float) and g["latency_ms"] > 0
    assert sum(bool(r["phi_deg"]) for r in table) >= MJPG_FRAMES // 2  # the check compared some
    # time.sleep(2 ms) lasts at least 2 ms: every row's measured time is at least that
    s = rep.on_row_ms
    assert s["n"] == MJPG_FRAMES and SLEEP_S * 1e3 <= s["p50_ms"] <= s["p99_ms"] <= s["max_ms"]
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["latency"]["on_row_ms"]["p99_ms"] == s["p99_ms"]


def test_a_raising_callback_stops_the_session_and_keeps_its_outputs(tmp_path, sensor):
    stop_at = 4

    def hook(row):
        if row["frame"] == stop_at:
            raise ValueError("robot said no")

    out = tmp_path / "live.csv"
    with pytest.raises(RowCallbackError, match=f"hook raised at frame {stop_at}: ValueError"
                       ) as err:  # fmt: skip
        cw.live_session(MJPG, out=out, sensor=SAMPLES / "nominal_mjpg.sensor.toml", mode="every",
                on_row=hook)  # fmt: skip
    assert isinstance(err.value.__cause__, ValueError)
    # The row is written before the callback sees it: frames 0..stop_at, stop_at + 1 rows.
    table = _table(out)
    assert [int(r["frame"]) for r in table] == list(range(stop_at + 1))
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["stopped_by"] == "on_row error"
    assert any(f"frame {stop_at}" in p for p in meta["problems"])
    assert meta["latency"]["on_row_ms"]["n"] == stop_at + 1


def test_live_rows_yields_every_row_in_order(sensor):
    rows = cw.live_rows(MJPG, sensor=sensor, mode="every")
    got = list(rows)
    assert [r["frame"] for r in got] == list(range(MJPG_FRAMES))
    assert rows.dropped == 0 and rows.report.rows == MJPG_FRAMES
    assert rows.report.stopped_by == "end of input"


def test_breaking_out_of_live_rows_stops_the_session(tmp_path, sensor):
    out = tmp_path / "live.csv"
    rows = cw.live_rows(CLIP, sensor=SAMPLES / "nominal.sensor.toml", out=out, mode="every")
    for row in rows:
        if row["frame"] == 4:
            break
    tic = time.monotonic()
    rows.close()
    stop_s = time.monotonic() - tic
    assert stop_s < 1.0, stop_s  # a stop is seen within POLL_S (0.1 s) plus one frame
    rep = rows.report
    assert rep.stopped_by == "closed" and 5 <= rep.rows < 90
    table = _table(out)  # every row so far, whole: the writer closed as on Ctrl-C
    assert [int(r["frame"]) for r in table] == list(range(rep.rows))
    assert json.loads(out.with_suffix(".json").read_text())["stopped_by"] == "closed"


def test_a_slow_consumer_gets_the_newest_rows_and_a_count_of_the_rest(sensor):
    got = []
    with cw.live_rows(MJPG, sensor=sensor, mode="every", maxsize=1) as rows:
        for row in rows:
            got.append(row["frame"])
            time.sleep(0.1)  # 3 frame periods per row: the queue of one overflows
    assert rows.dropped >= 1 and len(got) + rows.dropped == rows.report.rows == MJPG_FRAMES
    assert got == sorted(got) and got[-1] == MJPG_FRAMES - 1  # the newest row is never dropped


def test_a_missing_source_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.avi"):
        cw.live_rows(tmp_path / "nope.avi")


def test_live_rows_with_a_calibration_carry_the_tables_contact_cells(tmp_path, sensor):
    # docs/api.md's closed-loop example reads row["contact"]: with calib= every row has the
    # belief and MF's fields, and each equals the session's own table cell (contact exactly;
    # MF's r to the table's printed digits, 0.5e-4 mm).
    out = tmp_path / "live.csv"
    rows = list(cw.live_rows(CLIP, sensor=sensor, out=out, mode="every",
                             calib=SAMPLES / "space" / "calib.toml"))
    table = _table(out)
    assert len(rows) == len(table) == 90
    for row, cells in zip(rows, table, strict=True):
        assert {"contact_b", "contact", "r_mf_mm", "sigma_mf_mm"} <= set(row)
        assert str(row["contact"]) == cells["contact"]
        r = row["r_mf_mm"]
        assert (r is None and cells["r_mf_mm"] == "") or abs(r - float(cells["r_mf_mm"])) < 0.5e-4
    # Not vacuous: 81 rows have a belief (from the rest reference on), 81 are in contact and
    # 29 have MF's r on this clip; the bounds leave room for another machine's last bits.
    assert sum(c["contact_b"] != "" for c in table) >= 60
    assert sum(r["contact"] == 1 for r in rows) >= 60
    assert sum(r["r_mf_mm"] is not None for r in rows) >= 20
