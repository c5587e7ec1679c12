"""Decode benchmark: MJPG decoders per frame, and ``camwhisker batch`` against OpenCV's read.

    camwhisker dev decode-bench VIDEO.avi [--sensor FILE] [--rounds 3] [--cores 0]
                                          [--first-run CLIP]

For an MJPG video: each decoder's time per frame in this process (OpenCV's
``cv2.imdecode``, :func:`~camwhisker.io.sources.decode_jpeg`, PyAV's decode
with its bgr24 conversion), then, ``--rounds`` times alternated, a process
reading the video with ``cv2.VideoCapture`` (decode only, one thread, the
reads timed) and a ``camwhisker batch`` process (its wall clock, start-up
included): each per frame, and their ratio, median over the rounds. With
``--cores`` the processes are pinned (``taskset``), e.g. ``0`` for one core.
Also the process start-up (``camwhisker --help``). ``--first-run CLIP``
removes the compiled kernels' caches (numba's ``*.nbi``/``*.nbc`` under the
package) and times a batch of CLIP twice: the first run, and the next.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["decoder_ms", "clear_kernel_caches", "main"]

_CLI = "from camwhisker.cli import main; raise SystemExit(main())"
_CV_READ = ("import sys, time, cv2\n"
            "cap = cv2.VideoCapture(sys.argv[1], cv2.CAP_ANY, [cv2.CAP_PROP_N_THREADS, 1])\n"
            "n, t0 = 0, time.perf_counter()\n"
            "while cap.read()[0]:\n    n += 1\n"
            "print((time.perf_counter() - t0) / n)\n")  # fmt: skip


def _packets(video: Path, limit: int) -> list[bytes]:
    import av

    with av.open(str(video)) as container:
        stream = container.streams.video[0]
        if stream.codec_context.name != "mjpeg":
            raise SystemExit(f"{video}: not an MJPG video ({stream.codec_context.name})")
        out = []
        for packet in container.demux(stream):
            if packet.size > 0:
                out.append(bytes(packet))
            if len(out) == limit:
                break
    return out


def decoder_ms(video: Path, frames: int = 200) -> dict[str, tuple[float, float]]:
    """Median wall and CPU ms per frame of each decoder over the first ``frames`` frames
    of ``video``, the decoders taking turns on each frame (a loaded machine's drift
    falls on all alike)."""
    import av
    import cv2

    from camwhisker.io.sources import decode_jpeg

    cv2.setNumThreads(1)
    packets = _packets(video, frames)
    ctx = av.CodecContext.create("mjpeg", "r")
    ctx.thread_count = 1
    decoders = {
        "cv2.imdecode": lambda d: cv2.imdecode(np.frombuffer(d, np.uint8), cv2.IMREAD_COLOR),
        "decode_jpeg (libjpeg-turbo)": decode_jpeg,
        "PyAV decode + bgr24": lambda d: ctx.decode(av.Packet(d))[0].to_ndarray(format="bgr24"),
    }
    wall: dict[str, list[float]] = {name: [] for name in decoders}
    cpu: dict[str, list[float]] = {name: [] for name in decoders}
    for data in packets:
        for name, decode in decoders.items():
            tic, tic_cpu = time.perf_counter(), time.thread_time()
            decode(data)
            wall[name].append(time.perf_counter() - tic)
            cpu[name].append(time.thread_time() - tic_cpu)
    return {name: (1e3 * statistics.median(wall[name]), 1e3 * statistics.median(cpu[name]))
            for name in decoders}  # fmt: skip


def _run(cmd: list[str], cores: str | None) -> tuple[float, str]:
    """Wall seconds of a process and its output; a failure stops the benchmark."""
    cmd = (["taskset", "-c", cores] if cores else []) + cmd
    tic = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - tic
    if done.returncode not in (0, 1):  # 1: a table written, with problems named
        raise SystemExit(f"{' '.join(cmd)} failed:\n{done.stderr}")
    return wall, done.stdout


def _batch(video: Path, sensor: str | None, out: Path) -> list[str]:
    return [sys.executable, "-c", _CLI, "batch", str(video), "--out", str(out), "--quiet",
            *(["--sensor", sensor] if sensor else [])]  # fmt: skip


def _frames(video: Path) -> int:
    import av

    with av.open(str(video)) as container:
        return sum(1 for p in container.demux(video=0) if p.size > 0)


def clear_kernel_caches() -> int:
    """Remove numba's caches of the package's kernels; how many files."""
    root = Path(__file__).resolve().parents[1]
    files = [*root.rglob("__pycache__/*.nbi"), *root.rglob("__pycache__/*.nbc")]
    for f in files:
        f.unlink()
    return len(files)


def main(argv: list[str] | None = None) -> int:
    """``camwhisker dev decode-bench VIDEO``: decoders per frame; batch against OpenCV's read."""
    p = argparse.ArgumentParser(prog="camwhisker dev decode-bench", description=main.__doc__)
    p.add_argument("video", type=Path, help="an MJPG video (AVI)")
    p.add_argument("--sensor", help="the video's sensor file")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--cores", help="pin the processes to these cores (taskset -c)")
    p.add_argument("--first-run", type=Path, metavar="CLIP",
                   help="also time a batch of CLIP after removing the kernels' caches, and again")
    args = p.parse_args(argv)
    n = _frames(args.video)
    print(f"{args.video.name}: {n} frames; decoders, ms per frame (median, one thread, "
          "taking turns):")
    for name, (wall_ms, cpu_ms) in decoder_ms(args.video).items():
        print(f"  {name}: {wall_ms:.2f} wall, {cpu_ms:.2f} CPU")
    read, batch = [], []
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "t.csv"
        for _ in range(args.rounds):
            read.append(1e3 * float(_run([sys.executable, "-c", _CV_READ, str(args.video)],
                                         args.cores)[1]))  # fmt: skip
            batch.append(1e3 * _run(_batch(args.video, args.sensor, out), args.cores)[0] / n)
        startup = [_run([sys.executable, "-c", _CLI, "--help"], args.cores)[0]
                   for _ in range(args.rounds)]  # fmt: skip
        ratios = [b / r for b, r in zip(batch, read, strict=True)]
        print(f"cores: {args.cores or 'all'}; {args.rounds} rounds alternated, median:")
        print(f"  cv2.VideoCapture read (decode only): {statistics.median(read):.2f} ms/frame")
        print(f"  camwhisker batch (process wall): {statistics.median(batch):.2f} ms/frame")
        print(f"  ratio batch / read: {statistics.median(ratios):.2f}x "
              f"(rounds: {', '.join(f'{r:.2f}' for r in ratios)})")
        print(f"  start-up (camwhisker --help): {statistics.median(startup):.2f} s")
        if args.first_run:
            removed = clear_kernel_caches()
            clip = Path(tmp) / "clip.csv"
            first = _run(_batch(args.first_run, args.sensor, clip), args.cores)[0]
            second = _run(_batch(args.first_run, args.sensor, clip), args.cores)[0]
            print(f"first run ({removed} cache files removed): {first:.1f} s, next {second:.1f} s "
                  f"({first / second:.1f}x)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
