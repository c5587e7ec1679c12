"""``camwhisker overlay``: a video annotated with what the front end tracked."""

from __future__ import annotations

import sys

from camwhisker.cli.common import CommandError, feature_hints, features_arg, sensor_arg
from camwhisker.sensor.file import load_sensor

__all__ = ["add_overlay"]


def add_overlay(sub) -> None:
    # The arrows' scale is run.overlay's ARROW_SCALE, written out: importing it here would
    # load the front end's kernels into every command's start-up.
    p = sub.add_parser(
        "overlay",
        help="video -> annotated video (tracked points, fitted outline, motion arrows)",
        description="Draw on every frame the tracked corners and tip (a cross where one was "
        "not tracked), the fitted model's outline, each point's motion from rest at "
        "10x and the pose. Beside OUT: OUT.overlay.json (how it was made) and "
        "OUT.rest.png (the rest frame with every feature named).",
    )
    p.add_argument("video", help="a video file OpenCV can read, or a folder of images")
    p.add_argument("--out", required=True, metavar="ANNOTATED.mp4",
                   help="output .mp4 (H.264) or .avi (MJPG)")  # fmt: skip
    p.add_argument("--rest-frame", type=int, default=0, metavar="N", help="rest reference frame")
    p.add_argument("--frames", type=int, metavar="N", help="stop after N frames")
    p.add_argument("--scale", type=float, help="motion arrows' scale (default 10)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    sensor_arg(p)
    features_arg(p)
    p.set_defaults(func=_run_overlay)


def _run_overlay(args) -> int:
    from camwhisker.run.overlay import ARROW_SCALE, annotate_video
    from camwhisker.vision import FrontEndOptions

    if args.rest_frame < 0:
        raise CommandError(f"--rest-frame must be >= 0, got {args.rest_frame}")
    if args.frames is not None and args.frames < 1:
        raise CommandError(f"--frames must be >= 1, got {args.frames}")
    sensor = load_sensor(args.sensor)
    options = FrontEndOptions(features=feature_hints(args, sensor))
    report = annotate_video(args.video, sensor, args.out, options,
                            rest_index=args.rest_frame, max_frames=args.frames,
                            scale=ARROW_SCALE if args.scale is None else args.scale,
                            progress=not args.quiet)  # fmt: skip
    print(f"{report.frames} frames, {report.frames_ok} ok -> {report.out}, {report.sidecar}, "
          f"{report.rest_check}")  # fmt: skip
    for problem in report.problems:
        print(f"camwhisker overlay: problem: {problem}", file=sys.stderr)
    return 1 if report.problems else 0
