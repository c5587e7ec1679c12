"""Checks against the simulator's truth: chain, contact-bench, bench."""

from __future__ import annotations

import sys
from pathlib import Path

from camwhisker.cli.common import CommandError

__all__ = ["add_chain", "add_contact_bench", "add_bench"]


def add_chain(sub) -> None:
    p = sub.add_parser(
        "chain",
        help="batch, calibrate, contact and plots on a filmed stage experiment, "
        "checked against its truth",
    )
    p.add_argument("experiment", help="folder made by make-experiment (has experiment.toml)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder for summary.json, calib.toml, signals/, contact/ and the figures")
    p.add_argument("--jobs", type=int, default=2, help="videos processed in parallel")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run_chain)


def _run_chain(args) -> int:
    from camwhisker.bench.chain import ChainError, format_summary, run_chain

    try:
        summary = run_chain(args.experiment, args.out, args.jobs, progress=not args.quiet)
    except ChainError as exc:
        raise CommandError(str(exc)) from exc
    print(format_summary(summary))
    print(f"wrote {args.out}/summary.json, calib.toml, signals/, contact/ and fig*.png")
    return 0


def add_contact_bench(sub) -> None:
    p = sub.add_parser("contact-bench",
                       help="speed and error of the contact back end on simulated runs, "
                            "at the paper's noise and at our front end's")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulated runs")
    p.add_argument("--samples", type=int, default=100_000, help="samples for the timing")
    p.add_argument("--figures", metavar="DIR", help="write Fig. 8 and Fig. 9 style PNGs here")
    p.add_argument("--speeds", default="1,2.5,5", metavar="V,...",
                   help="base speeds (mm/s) of the continuous sweeps scored per frame, "
                        "beside the paused runs (default 1,2.5,5; empty: paused only)")
    p.set_defaults(func=_run_contact_bench)


def _run_contact_bench(args) -> int:
    from camwhisker.bench.contact import format_report, run_bench

    try:
        speeds = tuple(float(v) for v in args.speeds.split(",") if v.strip())
    except ValueError:
        raise CommandError(f"--speeds: not a list of numbers: {args.speeds!r}") from None
    if any(not v > 0 for v in speeds):
        raise CommandError(f"--speeds: speeds must be positive, got {args.speeds!r}")
    result = run_bench(args.seed, figures_dir=args.figures, n_timing=args.samples,
                       speeds_mm_s=speeds)
    print(format_report(result))
    if args.figures:
        print(f"wrote figures to {args.figures}")
    return 0


def add_bench(sub) -> None:
    p = sub.add_parser(
        "bench", help="speed against error: the front end, the paper's pipeline, other trackers"
    )
    p.add_argument("--out", required=True, metavar="MD", help="Markdown table to write")
    p.add_argument("--plot", metavar="PNG", help="frames/s against error plot (log axes)")
    p.add_argument("--frames", type=int, default=50, help="frames per scene (default 50)")
    p.add_argument("--scenes", default="nominal,distortion,hard", help="comma-separated scenes")
    p.add_argument("--configs", help="comma-separated configuration names (default: all)")
    p.add_argument("--cache", metavar="DIR", help="renders and bounds kept here (default: temp)")
    p.add_argument("--repeat", type=int, default=3,
                   help="time fast configurations this many times, keep the least (default 3)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=_run_bench)


def _run_bench(args) -> int:
    from camwhisker.bench.configs import select
    from camwhisker.bench.run import default_cache
    from camwhisker.bench.run import main as bench_main
    from camwhisker.bench.vision import SCENES

    configs = select(args.configs)
    scenes = [s.strip() for s in args.scenes.split(",")]
    unknown = [s for s in scenes if s not in SCENES]
    if unknown:
        raise CommandError(f"unknown scene {unknown[0]!r} (known: {', '.join(SCENES)})")
    if args.frames < 6:
        raise CommandError(f"--frames must be at least 6, got {args.frames}")
    cache = Path(args.cache) if args.cache else default_cache()
    log = None if args.quiet else (lambda line: print(line, file=sys.stderr, flush=True))
    text = bench_main(None, Path(args.out), Path(args.plot) if args.plot else None,
                      args.frames, scenes, configs, cache, log, max(args.repeat, 1))  # fmt: skip
    print(text)
    return 0
