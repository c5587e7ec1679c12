"""The live loop's latency with the browser view open and without (``camwhisker live --view``).

Renders a nominal clip (:data:`~camwhisker.bench.live.BENCH_SEED`) to MJPG, then
runs live sessions (:class:`~camwhisker.live.loop.LiveSession`, "latest" mode)
that play it at 30 frames/s through the playback capture, alternating two arms
in one run so that a drift of the machine's speed falls on both:

- ``closed``: no view;
- ``open``: the view served and its page open in headless Chromium (Debian's
  chromium and chromedriver, driven by selenium), polling pictures and rows as a
  user's page does.

One headless Chromium runs through the whole run; in the closed arm it shows
a blank page. Each session gives ``--rows`` rows; its first :data:`SKIP_ROWS`
(the rest frame, the rest averaging, the page loading) are left out. Prints,
per arm, the processing latency (frame handed to the loop -> row written) and
the end-to-end latency (frame read -> row written) pooled over the arm's
sessions: p50, p99, max; the p99 of each session; the pictures the view drew;
and the rise of p99 with the view open.

    camwhisker dev view-bench [--blocks 8 --rows 450]
"""

from __future__ import annotations

import argparse
import tempfile
import threading
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
        self.latencies: tuple[list[float], list[float]] = ([], [])

    def _row(self, frame, r, proc_s, writer, recorder, udp, proc_ms, e2e_ms):
        self.latencies = (proc_ms, e2e_ms)
        super()._row(frame, r, proc_s, writer, recorder, udp, proc_ms, e2e_ms)


def _session(video: Path, sensor: Sensor, out: Path, rows: int, view: bool, driver):
    """One session of ``rows`` rows; with ``view`` its page open in ``driver``.
    Returns (processing ms, end-to-end ms, pictures drawn)."""
    config = LiveConfig(controls=False, handle_signals=False, max_frames=rows,
                        view_port=0 if view else None)  # fmt: skip
    session = _TimedSession(PlaybackSource(video, RATE_FPS, loop=True), sensor, out, config)
    thread = threading.Thread(target=session.run)
    thread.start()
    if view:
        driver.get(session.view.url)
    thread.join()
    if view:
        driver.get("about:blank")
    proc, e2e = session.latencies
    pictures = session.view.pictures if view else 0
    return proc[SKIP_ROWS:], e2e[SKIP_ROWS:], pictures


def run_bench(blocks: int = 8, rows: int = 450) -> dict:
    """Alternate ``blocks`` sessions (closed, open, closed, ...); see the module notes."""
    if blocks < 2 or rows <= SKIP_ROWS:
        raise ValueError(f"need blocks >= 2 and rows > {SKIP_ROWS}, got {blocks}, {rows}")
    scenario = make_scenario("nominal", CLIP_FRAMES, BENCH_SEED)
    sensor = Sensor().replace(**scenario.sensor_changes) if scenario.sensor_changes else Sensor()
    arms = {"closed": {"proc": [], "e2e": [], "p99": [], "pictures": 0},
            "open": {"proc": [], "e2e": [], "p99": [], "pictures": 0}}  # fmt: skip
    driver = headless_chromium()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            video = render_scenario(scenario, sensor, Path(tmp) / "clip.avi", BENCH_SEED)["video"]
            for block in range(blocks):
                arm = "open" if block % 2 else "closed"
                proc, e2e, pictures = _session(video, sensor, Path(tmp) / f"b{block}.csv", rows,
                                               arm == "open", driver)  # fmt: skip
                a = arms[arm]
                a["proc"] += proc
                a["e2e"] += e2e
                a["p99"].append(float(np.percentile(proc, 99)))
                a["pictures"] += pictures
    finally:
        quit_chromium(driver)
    return {arm: {"processing": latency_summary(a["proc"]), "end_to_end": latency_summary(a["e2e"]),
                  "session_p99_ms": a["p99"], "pictures": a["pictures"]}
            for arm, a in arms.items()}  # fmt: skip


def text(result: dict, blocks: int, rows: int) -> str:
    lines = [f"live loop with the view closed / open: {blocks} sessions alternated, {rows} rows "
             f"each (first {SKIP_ROWS} left out), {RATE_FPS:g} frames/s, latest mode"]
    for arm, r in result.items():
        p, e = r["processing"], r["end_to_end"]
        lines.append(
            f"  {arm:6s}: processing p50 {p['p50_ms']:.2f} ms, p99 {p['p99_ms']:.2f} ms, "
            f"max {p['max_ms']:.2f} ms (n {p['n']}); end to end p50 {e['p50_ms']:.2f} ms, "
            f"p99 {e['p99_ms']:.2f} ms; sessions' p99 "
            + ", ".join(f"{x:.2f}" for x in r["session_p99_ms"])
            + f" ms; pictures drawn {r['pictures']}"
        )
    for key in ("processing", "end_to_end"):
        closed, opened = result["closed"][key]["p99_ms"], result["open"][key]["p99_ms"]
        lines.append(f"  {key.replace('_', ' ')} p99 rise with the view open: "
                     f"{100 * (opened / closed - 1):+.1f} %")  # fmt: skip
    # Each open session against the closed one before it: the machine's drift cancels.
    opened, closed = (np.array(result[a]["session_p99_ms"]) for a in ("open", "closed"))
    pairs = opened / closed
    lines.append(f"  processing p99, open session / the closed one before it: median "
                 f"{np.median(pairs):.2f}, range {pairs.min():.2f}-{pairs.max():.2f}")  # fmt: skip
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="camwhisker dev view-bench", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--blocks", type=int, default=8, help="sessions, alternating closed / open")
    p.add_argument("--rows", type=int, default=450, help="rows per session")
    args = p.parse_args(argv)
    try:
        result = run_bench(args.blocks, args.rows)
    except ValueError as exc:
        p.error(str(exc))
    print(text(result, args.blocks, args.rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
