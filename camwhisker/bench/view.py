"""The live loop's latency with the browser view open and without (``camwhisker live --view``),
or with the robot outputs on and off (``--robots``: ``live --mcap --lsl``).

Renders a nominal clip (:data:`~camwhisker.bench.live.BENCH_SEED`) to MJPG, then
runs live sessions (:class:`~camwhisker.live.loop.LiveSession`, "latest" mode)
that play it at 30 frames/s through the playback capture, alternating two arms
in one run so that a drift of the machine's speed falls on both:

- ``closed``: no view;
- ``open``: the view served and its page open in headless Chromium (Debian's
  chromium and chromedriver, driven by selenium), polling pictures and rows as a
  user's page does.

With ``--robots`` the arms are ``off`` (neither) and ``on``: the rows written to an
MCAP file with each frame's JPEG (``live --mcap``) and pushed to an LSL outlet
(``live --lsl``) that an inlet in another process reads as it comes (no browser);
``--robots lsl`` or ``--robots mcap``: the one alone. With LSL on, the push's own time
per row is printed too; with the MCAP on, the rows its writer's thread dropped.

One headless Chromium runs through the whole run; in the closed arm it shows
a blank page. Each session gives ``--rows`` rows; its first :data:`SKIP_ROWS`
(the rest frame, the rest averaging, the page loading) are left out. Prints,
per arm, the processing latency (frame handed to the loop -> row written) and
the end-to-end latency (frame read -> row written) pooled over the arm's
sessions: p50, p99, max; the p99 of each session; the pictures the view drew;
and the rise of p99 with the view open. End to end ends when the row's result is
known, before its outputs; "to outputs" (frame read -> the row in every output)
also holds the outputs' time.

    camwhisker dev view-bench [--blocks 8 --rows 450] [--robots [mcap,lsl|mcap|lsl]]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from camwhisker.bench.live import BENCH_SEED
from camwhisker.live.loop import LiveConfig, LiveSession, latency_summary
from camwhisker.live.playback import PlaybackSource
from camwhisker.sensor.file import Sensor
from camwhisker.sim.render.scenarios import make_scenario
from camwhisker.sim.render.video import render_scenario

__all__ = ["CHROMIUM_FLAGS", "SKIP_ROWS", "headless_chromium", "quit_chromium", "run_bench", "main"]

#: Rows left out at the start of each session: the rest frame (detection), the rest
#: averaging's rebuild (REST_FRAMES rows) and the page's loading.
SKIP_ROWS = 45
#: Camera rate the clip is played at (frames/s).
RATE_FPS = 30.0
#: Frames of the rendered clip (looped).
CLIP_FRAMES = 300
#: Chromium's flags on a machine without a display or a network (no sandbox as root).
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                  "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync",
                  "--window-size=1400,1000")  # fmt: skip


def headless_chromium():
    """Debian's chromium, headless, with a new empty profile (removed by ``quit_chromium``)."""
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError as exc:  # pragma: no cover - the test extra has it
        raise RuntimeError("the view's benchmark needs selenium: pip install -e '.[test]'") from exc
    options = webdriver.ChromeOptions()
    options.binary_location = "/usr/bin/chromium"
    for flag in CHROMIUM_FLAGS:
        options.add_argument(flag)
    profile = tempfile.TemporaryDirectory(prefix="camwhisker-chromium-")
    options.add_argument(f"--user-data-dir={profile.name}")
    driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
    driver.camwhisker_profile = profile
    return driver


def quit_chromium(driver) -> None:
    driver.quit()
    driver.camwhisker_profile.cleanup()


class _TimedSession(LiveSession):
    """A session that keeps its per-frame latencies (the loop's own lists)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.latencies: tuple[list[float], list[float], list[float]] = ([], [], [])
        #: The LSL output's own time per row (ms; empty without ``--lsl``).
        self.push_ms: list[float] = []
        if self._lsl is not None:
            push = self._lsl.push_row

            def timed(cells, t_s):
                tic = time.perf_counter()
                push(cells, t_s)
                self.push_ms.append(1e3 * (time.perf_counter() - tic))

            self._lsl.push_row = timed

    def _row(self, frame, r, proc_s, writer, recorder, udp, proc_ms, e2e_ms):
        out_ms = self.latencies[2]
        self.latencies = (proc_ms, e2e_ms, out_ms)
        super()._row(frame, r, proc_s, writer, recorder, udp, proc_ms, e2e_ms)
        if self._grabbed.image is not None:  # as e2e_ms: rows with a frame
            out_ms.append(1e3 * (time.monotonic() - self._grabbed.t_s))


#: The LSL consumer, a process of its own as a recorder or a robot's controller is: it
#: connects, says so, and pulls every 5 ms until the outlet closes.
_READER = """
import sys, time, pylsl
inlet = pylsl.StreamInlet(pylsl.resolve_byprop("name", sys.argv[1], 1, 5.0)[0], recover=False)
inlet.open_stream(5.0)
print("ready", flush=True)
while True:
    try:
        inlet.pull_chunk(timeout=0.0)
    except pylsl.util.LostError:
        break
    time.sleep(0.005)
"""


def _lsl_reader(name: str) -> subprocess.Popen:
    """A process reading the outlet ``name``, connected when this returns."""
    reader = subprocess.Popen([sys.executable, "-c", _READER, name], stdout=subprocess.PIPE,
                              stderr=subprocess.DEVNULL, text=True)  # fmt: skip
    if reader.stdout.readline().strip() != "ready":
        reader.kill()
        raise RuntimeError(f"the LSL reader did not connect to {name}")
    return reader


def _session(video: Path, sensor: Sensor, out: Path, rows: int, view: bool, driver,
             robots: tuple[str, ...] = ()):  # fmt: skip
    """One session of ``rows`` rows; with ``view`` its page open in ``driver``; with
    ``robots`` those outputs on ("mcap", "lsl"), the LSL outlet read. Returns (processing
    ms, end-to-end ms, to-outputs ms, LSL push ms, pictures drawn, MCAP rows dropped)."""
    name = f"camwhisker-bench-{os.getpid()}"
    config = LiveConfig(controls=False, handle_signals=False, max_frames=rows,
                        view_port=0 if view else None,
                        mcap=out.with_suffix(".mcap") if "mcap" in robots else None,
                        lsl=name if "lsl" in robots else None)  # fmt: skip
    session = _TimedSession(PlaybackSource(video, RATE_FPS, loop=True), sensor, out, config)
    reader = _lsl_reader(name) if "lsl" in robots else None
    thread = threading.Thread(target=session.run)
    thread.start()
    if view:
        driver.get(session.view.url)
    thread.join()
    if reader is not None:
        reader.wait()
    if view:
        driver.get("about:blank")
    proc, e2e, outs = session.latencies
    pictures = session.view.pictures if view else 0
    dropped = session._bag.dropped if session._bag is not None else 0
    return proc[SKIP_ROWS:], e2e[SKIP_ROWS:], outs[SKIP_ROWS:], session.push_ms, pictures, dropped


def run_bench(blocks: int = 8, rows: int = 450, robots: tuple[str, ...] = ()) -> dict:
    """Alternate ``blocks`` sessions (closed, open, closed, ...; with ``robots``, the
    outputs "mcap" and / or "lsl", off, on, off, ...); see the module notes."""
    if not set(robots) <= {"mcap", "lsl"}:
        raise ValueError(f"--robots takes mcap and / or lsl, got {','.join(robots)}")
    if blocks < 2 or rows <= SKIP_ROWS:
        raise ValueError(f"need blocks >= 2 and rows > {SKIP_ROWS}, got {blocks}, {rows}")
    scenario = make_scenario("nominal", CLIP_FRAMES, BENCH_SEED)
    sensor = Sensor().replace(**scenario.sensor_changes) if scenario.sensor_changes else Sensor()
    names = ("off", "on") if robots else ("closed", "open")
    arms = {arm: {"proc": [], "e2e": [], "out": [], "push": [], "p99": [], "out_p99": [],
                  "pictures": 0, "dropped": 0} for arm in names}  # fmt: skip
    driver = None if robots else headless_chromium()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            video = render_scenario(scenario, sensor, Path(tmp) / "clip.avi", BENCH_SEED)["video"]
            for block in range(blocks):
                arm = names[block % 2]
                second = arm == names[1]
                proc, e2e, outs, push, pictures, dropped = _session(
                    video, sensor, Path(tmp) / f"b{block}.csv", rows, second and not robots,
                    driver, robots if second else ())  # fmt: skip
                a = arms[arm]
                a["proc"] += proc
                a["e2e"] += e2e
                a["out"] += outs
                a["push"] += push
                a["p99"].append(float(np.percentile(proc, 99)))
                a["out_p99"].append(float(np.percentile(outs, 99)))
                a["pictures"] += pictures
                a["dropped"] += dropped
    finally:
        if driver is not None:
            quit_chromium(driver)
    return {arm: {"processing": latency_summary(a["proc"]), "end_to_end": latency_summary(a["e2e"]),
                  "to_outputs": latency_summary(a["out"]), "session_p99_ms": a["p99"],
                  "session_out_p99_ms": a["out_p99"], "pictures": a["pictures"],
                  "outputs": [f"--{o}" for o in robots] if arm == "on" else [],
                  "lsl_push": latency_summary(a["push"]), "mcap_dropped": a["dropped"]}
            for arm, a in arms.items()}  # fmt: skip


def text(result: dict, blocks: int, rows: int) -> str:
    first, second = result
    view = first == "closed"
    outputs = "" if view else " and ".join(result[second]["outputs"])
    lines = [f"live loop with {'the view' if view else outputs} {first} / {second}: {blocks} "
             f"sessions alternated, {rows} rows each (first {SKIP_ROWS} left out), "
             f"{RATE_FPS:g} frames/s, latest mode"]  # fmt: skip
    for arm, r in result.items():
        p, e = r["processing"], r["end_to_end"]
        o = r.get("to_outputs")
        lines.append(
            f"  {arm:6s}: processing p50 {p['p50_ms']:.2f} ms, p99 {p['p99_ms']:.2f} ms, "
            f"max {p['max_ms']:.2f} ms (n {p['n']}); end to end p50 {e['p50_ms']:.2f} ms, "
            f"p99 {e['p99_ms']:.2f} ms; "
            + (f"to outputs p50 {o['p50_ms']:.2f} ms, p99 {o['p99_ms']:.2f} ms; " if o else "")
            + "sessions' p99 " + ", ".join(f"{x:.2f}" for x in r["session_p99_ms"]) + " ms"
            + (f"; pictures drawn {r['pictures']}" if view else "")
            + ("; MCAP rows dropped " + str(r["mcap_dropped"]) if "--mcap" in r.get("outputs", ())
               else "")
        )
        push = r.get("lsl_push", {})
        if push.get("n"):
            lines.append(f"  {arm:6s}: the LSL push per row p50 {1e3 * push['p50_ms']:.1f} us, "
                         f"p99 {1e3 * push['p99_ms']:.1f} us, max {1e3 * push['max_ms']:.1f} us")
    rise = "with the view open" if view else f"with {outputs} on"
    for key in ("processing", "end_to_end", "to_outputs"):
        if key in result[first]:
            a, b = result[first][key]["p99_ms"], result[second][key]["p99_ms"]
            lines.append(f"  {key.replace('_', ' ')} p99 rise {rise}: "
                         f"{100 * (b / a - 1):+.1f} %")  # fmt: skip
    # Each second-arm session against the first-arm one before it: the machine's drift cancels.
    for key, label in (("session_p99_ms", "processing"), ("session_out_p99_ms", "to outputs")):
        if key not in result[first]:
            continue
        b, a = (np.array(result[arm][key]) for arm in (second, first))
        pairs = b / a
        lines.append(f"  {label} p99, {second} session / the {first} one before it: median "
                     f"{np.median(pairs):.2f}, range {pairs.min():.2f}-"
                     f"{pairs.max():.2f}")  # fmt: skip
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="camwhisker dev view-bench", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--blocks", type=int, default=8, help="sessions, alternating closed / open")
    p.add_argument("--rows", type=int, default=450, help="rows per session")
    p.add_argument("--robots", nargs="?", const="mcap,lsl", metavar="mcap,lsl",
                   help="arms off / on: the rows to MCAP (--mcap) and LSL (--lsl), or the one "
                        "named, not the view")
    args = p.parse_args(argv)
    robots = tuple(args.robots.split(",")) if args.robots else ()
    try:
        result = run_bench(args.blocks, args.rows, robots)
    except ValueError as exc:
        p.error(str(exc))
    print(text(result, args.blocks, args.rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
