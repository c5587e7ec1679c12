"""Batch throughput: frames/s of a campaign with 1 worker against 2, one Markdown table.

    camwhisker dev throughput-bench VIDEO... [--copies N] [--jobs 1 2]

Beside it, the machine's own 2-process speed-up on pure-Python work: the
ceiling that independent CPU-bound processes can reach on these cores.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from camwhisker.run.campaign import BatchTask, CampaignError, run_many
from camwhisker.sensor.file import Sensor


def throughput(videos: Sequence[Path], jobs: int, out_dir: Path) -> dict:
    """Frames/s of a fresh batch over ``videos`` with ``jobs`` local workers (wall clock)."""
    tasks = [(Path(v), Path(out_dir) / f"{i:03d}_{Path(v).stem}.csv") for i, v in enumerate(videos)]
    t0 = time.perf_counter()
    summary = run_many(tasks, BatchTask(Sensor()), jobs=jobs, overwrite=True, progress=False)
    seconds = time.perf_counter() - t0
    if summary.failed:
        raise CampaignError(summary.report())
    return {
        "jobs": jobs,
        "videos": len(tasks),
        "frames": summary.frames,
        "seconds": seconds,
        "frames_per_s": summary.frames / seconds,
    }


def _spin(n: int) -> int:
    total = 0
    for i in range(n):
        total += i * i
    return total


def two_process_ceiling(n: int = 20_000_000) -> float:
    """Speed-up of 2 processes over 1 on a pure-Python loop: what the machine's cores
    give to independent CPU-bound work, with no memory traffic to share."""
    t0 = time.perf_counter()
    _spin(n)
    _spin(n)
    one = time.perf_counter() - t0
    with ProcessPoolExecutor(max_workers=2) as pool:
        t0 = time.perf_counter()
        list(pool.map(_spin, [n, n]))
        two = time.perf_counter() - t0
    return one / two


def main(argv: list[str] | None = None) -> int:
    """``camwhisker dev throughput-bench VIDEO... [--copies N]``: 1 worker against 2."""
    import argparse
    import tempfile

    p = argparse.ArgumentParser(prog="camwhisker dev throughput-bench",
                                description=main.__doc__)
    p.add_argument("videos", nargs="+")
    p.add_argument("--copies", type=int, default=4, help="each video this many times")
    p.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    args = p.parse_args(argv)
    videos = [Path(v) for v in args.videos] * args.copies
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for jobs in args.jobs:
            rows.append(throughput(videos, jobs, Path(tmp) / f"jobs{jobs}"))
    base = rows[0]["frames_per_s"]
    print(
        f"{len(videos)} videos, {rows[0]['frames']} frames; {os.cpu_count()} cores, "
        f"load average at end {os.getloadavg()[0]:.2f}; the machine's own 2-process "
        f"speed-up on pure-Python work: {two_process_ceiling():.2f}x"
    )
    print("| workers | seconds | frames/s | speed-up |")
    print("|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['jobs']} | {r['seconds']:.1f} | {r['frames_per_s']:.1f} | "
            f"{r['frames_per_s'] / base:.2f}x |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
