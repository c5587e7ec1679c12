"""``camwhisker batch``: video(s) -> signal table(s), one or many at once."""

from __future__ import annotations

import sys
from pathlib import Path

from camwhisker.cli.common import (
    CommandError,
    feature_hints,
    features_arg,
    mode_arg,
    sensor_arg,
    springs_arg,
    springs_of,
)
from camwhisker.sensor.file import load_sensor

__all__ = ["add_batch", "tracker_args"]


def add_batch(sub) -> None:
    p = sub.add_parser(
        "batch",
        help="video(s) -> signal table(s) (dz, phi, theta per frame)",
        description="One video with --out: its signal table, its sidecar OUT.json and the rest "
        "frame's check image OUT.rest.png (the features named). Many videos, folders or globs: "
        "one table each, beside the input or under --dest, skipping outputs already complete.",
    )
    p.add_argument(
        "video",
        nargs="+",
        help="video files OpenCV can read, folders, globs; or one folder of images with --out",
    )
    p.add_argument("--out", metavar="OUT.csv", help="signal table of a single input")
    p.add_argument("--mcap", metavar="FILE.mcap",
                   help="single input: also the table as ROS 2 messages in an MCAP file, "
                   "/whisker/signals and, with --springs, /whisker/wrench (docs/robots.md; "
                   "pip install 'camwhisker[ros]')")  # fmt: skip
    p.add_argument("--dest", metavar="DIR", help="many inputs: write the tables under DIR, "
                   "mirroring each input's folder as seen from DIR's parent")  # fmt: skip
    p.add_argument(
        "--format", choices=("csv", "parquet"), default="csv", help="many inputs: table format"
    )
    p.add_argument(
        "--jobs",
        type=int,
        default=1,
        metavar="N",
        help="many inputs: N local processes, one OpenCV thread each",
    )
    p.add_argument(
        "--scheduler", metavar="ADDRESS", help="many inputs: run on this Dask distributed scheduler"
    )
    p.add_argument("--overwrite", action="store_true", help="redo outputs already complete")
    mode_arg(p)
    p.add_argument("--no-shift", action="store_true", help="do not fit the lateral shift")
    p.add_argument("--lock-gains", action="store_true", help="keep the rest frame's white balance")
    tracker_args(p)
    p.add_argument("--rest-frame", type=int, default=0, metavar="N", help="rest reference frame")
    p.add_argument("--fps", type=float, help="frame rate of an image folder")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    sensor_arg(p)
    features_arg(p)
    springs_arg(p)
    p.set_defaults(func=_run_batch)


def tracker_args(p) -> None:
    """The front end's tuning knobs (FrontEndOptions; `camwhisker dev bench` compares them).
    Their defaults stay the front end's own: reading them here would import numba's kernels
    into every command's start-up."""
    p.add_argument("--lk-half-px", type=int, metavar="N",
                   help="half size of a corner's template (default: the front end's, 12)")
    p.add_argument("--roi-margin-px", type=int, metavar="N",
                   help="region of interest beyond the LK window (default: the front end's, 20)")


def _run_batch(args) -> int:
    from camwhisker.vision import FrontEndOptions

    if args.rest_frame < 0:
        raise CommandError(f"--rest-frame must be >= 0, got {args.rest_frame}")
    sensor = load_sensor(args.sensor)
    options = FrontEndOptions(
        mode=args.mode,
        fit_shift=not args.no_shift,
        lock_gains=args.lock_gains,
        **{k: v for k, v in (("lk_half_px", args.lk_half_px),
                             ("roi_margin_px", args.roi_margin_px)) if v is not None},
        features=feature_hints(args, sensor),
    )
    if args.out is None:
        if args.mcap:
            raise CommandError("--mcap goes with --out (a single input)")
        return _run_batch_many(args, sensor, options)
    if len(args.video) != 1 or args.dest:
        raise CommandError("--out takes a single input; for many use --dest (or neither)")
    if args.mcap:
        from camwhisker.io.bag import ros_modules

        ros_modules()  # a missing extra stops the command before the video, not after
        if Path(args.mcap).resolve() == Path(args.out).resolve():
            raise CommandError(f"--mcap {args.mcap} would overwrite the table --out")
    from camwhisker.run.batch import run_batch
    from camwhisker.run.workers import stop_signals_interrupt

    bag = None
    with stop_signals_interrupt():  # SIGTERM unwinds as Ctrl-C does: no temporary file left
        report = run_batch(
            args.video[0], sensor, args.out, options, args.rest_frame, args.fps, not args.quiet,
            springs=springs_of(args),
        )
        if args.mcap:
            from camwhisker.io.bag import write_table_bag

            bag = write_table_bag(report.out_csv, args.mcap)
    outputs = ", ".join(str(p) for p in (report.out_csv, report.sidecar, report.rest_check, bag)
                        if p)  # fmt: skip
    print(f"{report.frames} frames, {report.frames_ok} ok -> {outputs}")
    for problem in report.problems:
        print(f"camwhisker batch: problem: {problem}", file=sys.stderr)
    return 1 if report.problems else 0


def _run_batch_many(args, sensor, options) -> int:
    from camwhisker.run.campaign import BatchTask, expand_inputs, output_path, run_many

    videos = expand_inputs(args.video)
    dest = Path(args.dest) if args.dest else None
    tasks = [(v, output_path(v, dest, "." + args.format)) for v in videos]
    task = BatchTask(sensor, options, rest_index=args.rest_frame, fps=args.fps,
                     springs=springs_of(args))  # fmt: skip
    summary = run_many(tasks, task, args.jobs, args.scheduler, args.overwrite, not args.quiet)
    print(summary.report())
    if summary.interrupted:
        return 130  # 128 + SIGINT, as a shell reports a command stopped by Ctrl-C
    return 1 if summary.failed else 0
