"""The ``camwhisker`` command line: wiring only, every computation lives in the library."""

from __future__ import annotations

import argparse
import sys

from camwhisker import __version__
from camwhisker.sensor import SensorFileError, load_sensor
from camwhisker.synth.scenarios import SCENARIOS


class CommandError(RuntimeError):
    """A user-facing failure: printed without a traceback, exit status 2."""


def _sensor_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sensor", metavar="FILE", help="sensor file (TOML); default: Table I values")


# --- synthetic data ------------------------------------------------------------------------


def _add_render(sub) -> None:
    p = sub.add_parser("render", help="render a synthetic scenario to video with its truth")
    p.add_argument("scenario", choices=sorted(SCENARIOS), help="what to render")
    p.add_argument("--out", required=True, metavar="VIDEO", help="output .avi (MJPG) or .mp4")
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--fps", type=float, default=30.0)
    _sensor_arg(p)
    p.set_defaults(func=_run_render)


def _run_render(args) -> int:
    from camwhisker.synth.scenarios import make_scenario
    from camwhisker.synth.video import render_scenario

    try:
        scenario = make_scenario(args.scenario, args.frames, args.seed, args.fps)
    except ValueError as exc:
        raise CommandError(str(exc)) from exc
    paths = render_scenario(scenario, load_sensor(args.sensor), args.out, args.seed, True)
    for kind, path in paths.items():
        print(f"{kind:>6}: {path}")
    return 0


def _add_bound(sub) -> None:
    p = sub.add_parser("bound", help="Cramér-Rao bound on dz, phi, theta for a scene")
    p.add_argument(
        "--scenario",
        default="nominal",
        choices=sorted(SCENARIOS),
        help="whose camera and artefacts to use",
    )
    p.add_argument("--dz-mm", type=float, default=0.5)
    p.add_argument("--phi-deg", type=float, default=15.0)
    p.add_argument("--theta-deg", type=float, default=30.0)
    p.add_argument("--with-shift", action="store_true", help="estimate sx, sy as nuisances too")
    _sensor_arg(p)
    p.set_defaults(func=_run_bound)


def _run_bound(args) -> int:
    from camwhisker.plate import Pose
    from camwhisker.synth.bound import pose_bound
    from camwhisker.synth.scenarios import make_scenario

    try:
        scenario = make_scenario(args.scenario, 30, 0)  # only its camera is used
    except ValueError as exc:
        raise CommandError(str(exc)) from exc
    sensor = load_sensor(args.sensor)
    if scenario.sensor_changes:
        sensor = sensor.replace(**scenario.sensor_changes)
    pose = Pose.from_degrees(args.dz_mm, args.phi_deg, args.theta_deg)
    params = ["dz_mm", "phi_deg", "theta_deg"] + (["sx_mm", "sy_mm"] if args.with_shift else [])
    bound = pose_bound(sensor, pose, scenario.artefacts, params)
    a = scenario.artefacts
    print(
        f"Cramér-Rao bound (1 sd), scene {scenario.name!r}: noise {a.noise_dn} DN at mid grey, "
        f"blur {a.blur_sigma_px} px; pose dz {args.dz_mm} mm, phi {args.phi_deg} deg, "
        f"theta {args.theta_deg} deg"
    )
    for name, sd in bound.items():
        print(f"  {name:<10} {sd:.3g}")
    return 0


def _add_samples(sub) -> None:
    p = sub.add_parser("make-samples", help="regenerate the bundled sample videos")
    p.add_argument("--dest", default="sample_frames", metavar="DIR")
    p.set_defaults(func=_run_samples)


def _run_samples(args) -> int:
    from camwhisker.synth.samples import make_samples

    for path in make_samples(args.dest):
        print(path)
    return 0


def _add_describe(sub) -> None:
    p = sub.add_parser("describe", help="decode a video and summarise it and its truth")
    p.add_argument("video")
    p.set_defaults(func=_run_describe)


def _run_describe(args) -> int:
    from camwhisker.synth.samples import describe_video

    try:
        info = describe_video(args.video)
    except ValueError as exc:
        raise CommandError(str(exc)) from exc
    for key, value in info.items():
        print(f"{key:>16}: {value}")
    return 0


def _add_experiment(sub) -> None:
    p = sub.add_parser(
        "make-experiment",
        help="simulate a stage experiment and film it (videos, stage logs, truth)",
    )
    p.add_argument("--dest", default="sample_frames/experiment", metavar="DIR")
    p.add_argument("--seed", type=int, default=8)
    p.add_argument("--jobs", type=int, default=2, help="runs rendered in parallel")
    p.set_defaults(func=_run_experiment)


def _run_experiment(args) -> int:
    from camwhisker.synth.experiment import render_experiment

    print(render_experiment(args.dest, args.seed, jobs=args.jobs))
    return 0


# --- vision front end ------------------------------------------------------------------------


def _add_batch(sub) -> None:
    p = sub.add_parser(
        "batch",
        help="video(s) -> signal table(s) (dz, phi, theta per frame)",
        description="One video with --out: its signal table. Many videos, folders or globs: "
        "one table each, beside the input or under --dest, skipping outputs already complete.",
    )
    p.add_argument(
        "video",
        nargs="+",
        help="video files OpenCV can read, folders, globs; or one folder of images with --out",
    )
    p.add_argument("--out", metavar="OUT.csv", help="signal table of a single input")
    p.add_argument("--dest", metavar="DIR", help="many inputs: write the tables under DIR")
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
    p.add_argument(
        "--mode",
        choices=("model", "paper"),
        default="model",
        help="exact camera model (default) or the paper's eqs. 2-7",
    )
    p.add_argument("--no-shift", action="store_true", help="do not fit the lateral shift")
    p.add_argument("--lock-gains", action="store_true", help="keep the rest frame's white balance")
    _tracker_args(p)
    p.add_argument("--rest-frame", type=int, default=0, metavar="N", help="rest reference frame")
    p.add_argument("--fps", type=float, help="frame rate of an image folder")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    _sensor_arg(p)
    p.set_defaults(func=_run_batch)


def _tracker_args(p) -> None:
    """The front end's tuning knobs (FrontEndOptions; `camwhisker bench` compares them)."""
    from camwhisker.vision import FrontEndOptions

    d = FrontEndOptions()
    p.add_argument("--lk-half-px", type=int, default=d.lk_half_px, metavar="N",
                   help=f"half size of a corner's template (default {d.lk_half_px})")
    p.add_argument("--roi-margin-px", type=int, default=d.roi_margin_px, metavar="N",
                   help=f"region of interest beyond the LK window (default {d.roi_margin_px})")


def _run_batch(args) -> int:
    from camwhisker.sources import SourceError
    from camwhisker.vision import FeaturesNotFound, FrontEndOptions

    if args.rest_frame < 0:
        raise CommandError(f"--rest-frame must be >= 0, got {args.rest_frame}")
    try:
        options = FrontEndOptions(
            args.mode, not args.no_shift, args.lock_gains, args.lk_half_px, args.roi_margin_px,
        )  # fmt: skip
    except ValueError as exc:
        raise CommandError(str(exc)) from exc
    sensor = load_sensor(args.sensor)
    if args.out is None:
        return _run_batch_many(args, sensor, options)
    if len(args.video) != 1 or args.dest:
        raise CommandError("--out takes a single input; for many use --dest (or neither)")
    from camwhisker.batch import run_batch

    try:
        report = run_batch(
            args.video[0], sensor, args.out, options, args.rest_frame, args.fps, not args.quiet
        )
    except (SourceError, FeaturesNotFound) as exc:
        raise CommandError(str(exc)) from exc
    print(f"{report.frames} frames, {report.frames_ok} ok -> {report.out_csv}, {report.sidecar}")
    for problem in report.problems:
        print(f"camwhisker batch: problem: {problem}", file=sys.stderr)
    return 3 if report.problems else 0


def _run_batch_many(args, sensor, options) -> int:
    from pathlib import Path

    from camwhisker.campaign import BatchTask, CampaignError, expand_inputs, output_path, run_many

    try:
        videos = expand_inputs(args.video)
    except CampaignError as exc:
        raise CommandError(str(exc)) from exc
    dest = Path(args.dest) if args.dest else None
    tasks = [(v, output_path(v, dest, "." + args.format)) for v in videos]
    task = BatchTask(sensor, options, rest_index=args.rest_frame, fps=args.fps)
    summary = run_many(tasks, task, args.jobs, args.scheduler, args.overwrite, not args.quiet)
    print(summary.report())
    return 3 if summary.failed else 0


# --- live processing -------------------------------------------------------------------------


def _add_list_cameras(sub) -> None:
    p = sub.add_parser("list-cameras", help="capture devices (V4L2) and their stable names")
    p.add_argument("--all", action="store_true", help="also the nodes that cannot capture")
    p.add_argument(
        "--sysfs",
        default="/sys/class/video4linux",
        metavar="DIR",
        help="video4linux class folder (another tree for tests)",
    )
    p.add_argument("--dev", default="/dev", metavar="DIR", help="device folder (with v4l/by-id)")
    p.set_defaults(func=_run_list_cameras)


def _run_list_cameras(args) -> int:
    from pathlib import Path

    from camwhisker.live.cameras import format_camera_list, list_cameras

    cameras = list_cameras(Path(args.sysfs), Path(args.dev), include_metadata=args.all)
    print(format_camera_list(cameras))
    return 0 if cameras else 1


def _add_live(sub) -> None:
    p = sub.add_parser("live", help="camera (or file at camera rate) -> signals within ms")
    p.add_argument(
        "source", nargs="?", help="camera index, /dev/videoN or by-id name; or a video / folder"
    )
    p.add_argument("--out", metavar="OUT.csv", help="signal table, flushed per row (+ OUT.json)")
    p.add_argument(
        "--mode",
        choices=("latest", "every"),
        default="latest",
        help="latest: drop stale frames (control); every: keep all",
    )
    p.add_argument("--record", metavar="SESSION.avi", help="record the frames (MJPG + timestamps)")
    p.add_argument("--udp", type=int, metavar="PORT", help="one JSON datagram per frame")
    p.add_argument("--udp-host", default="127.0.0.1", help="UDP destination (default: this host)")
    p.add_argument("--jsonl", action="store_true", help="one JSON line per frame on stdout")
    p.add_argument(
        "--playback-fps", type=float, metavar="FPS", help="play a file at this rate, like a camera"
    )
    p.add_argument("--loop", action="store_true", help="loop a played-back file")
    p.add_argument("--frames", type=int, metavar="N", help="stop after N rows (bench: clip length)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument("--no-keys", action="store_true", help="no r/d/q keys even on a terminal")
    p.add_argument("--raw-mjpg", action="store_true", help="take the camera's JPEG bytes as sent")
    p.add_argument(
        "--no-lock",
        action="store_true",
        help="leave auto white balance and exposure as the camera has them",
    )
    p.add_argument("--exposure", type=float, help="manual exposure (driver units)")
    p.add_argument("--bench", action="store_true", help="latency benchmark (one core), then exit")
    p.add_argument(
        "--mode-front",
        choices=("model", "paper"),
        default="model",
        help="front end: exact camera model or the paper's eqs. 2-7",
    )
    _sensor_arg(p)
    p.set_defaults(func=_run_live)


def _run_live(args) -> int:
    import logging
    import sys
    from dataclasses import replace
    from pathlib import Path

    from camwhisker.live.cameras import C310_PROFILE
    from camwhisker.live.capture import CaptureError, open_capture
    from camwhisker.live.loop import LiveConfig, LiveSession
    from camwhisker.sources import SourceError
    from camwhisker.vision import FrontEndOptions

    if args.bench:
        from camwhisker.live.bench import run_bench

        print(run_bench(args.frames or 150).text())
        return 0
    if not args.source or not args.out:
        raise CommandError("live needs a SOURCE and --out (or --bench)")
    logging.basicConfig(level=logging.INFO, format="camwhisker live: %(message)s")
    profile = C310_PROFILE
    if args.no_lock:
        profile = replace(profile, auto_wb=None, auto_exposure=None)
    if args.exposure is not None:
        profile = replace(profile, exposure=args.exposure)
    sensor = load_sensor(args.sensor)
    try:
        capture = open_capture(args.source, profile, args.playback_fps, raw_mjpg=args.raw_mjpg)
        if args.loop and hasattr(capture, "loop"):
            capture.loop = True
    except (CaptureError, SourceError) as exc:
        raise CommandError(str(exc)) from exc
    config = LiveConfig(
        mode=args.mode,
        options=FrontEndOptions(args.mode_front),
        record=Path(args.record) if args.record else None,
        record_rate_fps=args.playback_fps or profile.fps,
        udp_port=args.udp,
        udp_host=args.udp_host,
        jsonl=args.jsonl,
        controls=False if args.no_keys else None,
        max_frames=args.frames,
        duration_s=args.duration,
    )
    report = LiveSession(capture, sensor, args.out, config).run()
    print(LiveSession.summary(report), file=sys.stderr)
    for problem in report.problems:
        print(f"camwhisker live: problem: {problem}", file=sys.stderr)
    return 3 if report.grabber.get("lost") else 0


def _add_replay(sub) -> None:
    p = sub.add_parser("replay", help="a recorded live session -> its signal table again")
    p.add_argument("session", help="SESSION.avi recorded by 'camwhisker live --record'")
    p.add_argument("--out", required=True, metavar="OUT.csv")
    p.add_argument("--mode-front", choices=("model", "paper"), default="model")
    _sensor_arg(p)
    p.set_defaults(func=_run_replay)


def _run_replay(args) -> int:
    from camwhisker.live.loop import reprocess_session
    from camwhisker.sources import SourceError
    from camwhisker.vision import FrontEndOptions

    try:
        out = reprocess_session(
            args.session, load_sensor(args.sensor), args.out, FrontEndOptions(args.mode_front)
        )
    except (SourceError, ValueError) as exc:
        raise CommandError(str(exc)) from exc
    print(out)
    return 0


# --- contact back end -------------------------------------------------------------------------


def _add_contact(sub) -> None:
    """simulate-stage, calibrate, contact, contact-bench (camwhisker.contact.commands)."""
    from camwhisker.contact.commands import add_commands

    add_commands(sub, CommandError)


# --- the whole chain ----------------------------------------------------------------------------


def _add_chain(sub) -> None:
    p = sub.add_parser(
        "chain",
        help="batch, calibrate, contact and plots on a filmed stage experiment, "
        "checked against its truth",
    )
    p.add_argument("experiment", help="folder made by make-experiment (has experiment.toml)")
    p.add_argument("--out", required=True, metavar="DIR")
    p.add_argument("--jobs", type=int, default=2, help="videos processed in parallel")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run_chain)


def _run_chain(args) -> int:
    from camwhisker.chain import ChainError, format_summary, run_chain

    try:
        summary = run_chain(args.experiment, args.out, args.jobs, progress=not args.quiet)
    except (ChainError, ValueError) as exc:
        raise CommandError(str(exc)) from exc
    print(format_summary(summary))
    print(f"wrote {args.out}/summary.json, calib.toml, signals/, contact/ and fig*.png")
    return 0


# --- benchmark ---------------------------------------------------------------------------------


def _add_bench(sub) -> None:
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
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_run_bench)


def _run_bench(args) -> int:
    from pathlib import Path

    from camwhisker.bench.configs import select
    from camwhisker.bench.run import default_cache
    from camwhisker.bench.run import main as bench_main
    from camwhisker.vision.bench import SCENES

    try:
        configs = select(args.configs)
    except ValueError as exc:
        raise CommandError(str(exc)) from exc
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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="camwhisker", description=__doc__)
    parser.add_argument("--version", action="version", version=f"camwhisker {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for add in _COMMANDS:
        add(sub)
    return parser


_COMMANDS: list = [
    _add_render,
    _add_bound,
    _add_samples,
    _add_describe,
    _add_experiment,
    _add_chain,
    _add_contact,
    _add_batch,
    _add_list_cameras,
    _add_live,
    _add_replay,
    _add_bench,
]


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (CommandError, SensorFileError, FileNotFoundError) as exc:
        print(f"camwhisker {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"camwhisker {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
