"""A batch against OpenCV's decode-only read of the same video, side by side, one core.

    camwhisker dev batch-bench [--video V] [--sensor S] [--rounds 3] [--core 1]

The video: V's frames played forward, back and forward again (900 frames of the
build's 360-frame sweep), written as MJPG at quality 88 into an .avi in a temporary
folder, as a webcam records. Each round runs, as fresh processes pinned to one core
(``taskset``), a ``cv2.VideoCapture`` read loop over it and ``camwhisker batch`` on it
(progress bar on, start-up included), and prints their wall and CPU seconds and the
batch's ratio to the read.
"""

from __future__ import annotations

import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2

__all__ = ["make_video", "run_timed", "main"]

ROOT = Path(__file__).resolve().parents[2]
VIDEO = ROOT / "sample_frames" / "build" / "sweep.mp4"
SENSOR = ROOT / "sample_frames" / "build" / "true.sensor.toml"
FRAMES = 900
MJPG_QUALITY = 88
#: The decode-only read: what the batch's own source does per frame, and nothing else.
READ_LOOP = """
import sys, cv2
cap = cv2.VideoCapture(sys.argv[1])
while cap.read()[0]:
    pass
"""


def make_video(source: Path, out: Path, frames: int = FRAMES, quality: int = MJPG_QUALITY) -> int:
    """``source``'s frames forward, back, forward ... up to ``frames``, as MJPG at
    ``quality`` into ``out`` (.avi); returns the frames written."""
    cap = cv2.VideoCapture(str(source))
    images = []
    while (got := cap.read())[0]:
        images.append(got[1])
    fps = cap.get(cv2.CAP_PROP_FPS) or 30.0
    cap.release()
    if not images:
        raise ValueError(f"{source}: no frame OpenCV can read")
    loop = images + images[::-1]
    h, w = images[0].shape[:2]
    writer = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*"MJPG"), fps, (w, h))
    writer.set(cv2.VIDEOWRITER_PROP_QUALITY, quality)
    for i in range(frames):
        writer.write(loop[i % len(loop)])
    writer.release()
    return frames


def run_timed(cmd: list[str], cwd: Path) -> tuple[float, float]:
    """Wall and CPU seconds (user + system) of a command run to its end."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, cwd=cwd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main(argv: list[str] | None = None) -> int:
    """``camwhisker dev batch-bench``: batch against the decode-only read, alternated."""
    import argparse

    p = argparse.ArgumentParser(prog="camwhisker dev batch-bench", description=main.__doc__)
    p.add_argument("--video", type=Path, default=VIDEO,
                   help="frames to loop (default: %(default)s)")  # fmt: skip
    p.add_argument("--sensor", type=Path, default=SENSOR, help="its sensor file")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--core", type=int, default=1, help="the one core both run on (taskset)")
    args = p.parse_args(argv)
    pin = ["taskset", "-c", str(args.core)] if shutil.which("taskset") else []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        video = tmp / "loop.avi"
        n = make_video(args.video, video)
        read = [*pin, sys.executable, "-c", READ_LOOP, str(video)]
        batch = [*pin, sys.executable, "-m", "camwhisker.cli", "batch", str(video),
                 "--sensor", str(args.sensor.resolve()), "--out", str(tmp / "out.csv")]  # fmt: skip
        print(f"{n} frames {args.video.name} forward/back, MJPG quality {MJPG_QUALITY}; "
              f"{'core ' + str(args.core) if pin else 'no taskset: all cores'}; "
              f"load average at start {os.getloadavg()[0]:.2f}")  # fmt: skip
        print("| round | read wall s | read CPU s | batch wall s | batch CPU s | wall ratio "
              "| CPU ratio |")
        print("|---|---|---|---|---|---|---|")
        ratios = []
        for k in range(args.rounds):
            rw, rc = run_timed(read, tmp)
            bw, bc = run_timed(batch, tmp)
            ratios.append(bw / rw)
            print(f"| {k} | {rw:.2f} | {rc:.2f} | {bw:.2f} | {bc:.2f} | {bw / rw:.2f}x | "
                  f"{bc / rc:.2f}x |", flush=True)  # fmt: skip
        print(f"median wall ratio {sorted(ratios)[len(ratios) // 2]:.2f}x; load average at end "
              f"{os.getloadavg()[0]:.2f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
