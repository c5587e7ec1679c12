"""``camwhisker calibrate-sensor``: a build's sensor file from its own sweep videos."""

from __future__ import annotations

import sys
from pathlib import Path

from camwhisker.calibration import MAX_ROUNDS
from camwhisker.cli.common import (
    CommandError,
    command_line,
    feature_hints,
    features_arg,
    sensor_arg,
)

__all__ = ["add_calibrate_sensor"]

_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def add_calibrate_sensor(sub) -> None:
    p = sub.add_parser(
        "calibrate-sensor",
        help="sweep videos + the square's side -> the build's sensor file (bundle adjustment)",
        description="Fit the camera intrinsics and the plate geometry of a hand-made sensor to "
        "videos of a free sweep (each starting with ~10 frames at rest, then the whisker "
        "pushed in all directions, phi up to ~30 deg), with the square's side measured with "
        "calipers, or videos of known axial steps with their stage logs, fixing the scale. "
        "Beside OUT: OUT.report.json and OUT.report.png (every "
        "parameter's value and standard error, residuals per point and per frame, warnings).",
    )
    p.add_argument("videos", nargs="+", metavar="VIDEO", help="sweep videos, each from rest")
    sensor_arg(p, "the nominal sensor file to start from; default: Table I values")
    p.add_argument("--square-side-mm", type=float, metavar="L",
                   help="the square's side measured with calipers (mm)")  # fmt: skip
    p.add_argument("--dz-steps", nargs=2, action="append", default=[], metavar=("VIDEO", "LOG"),
                   help="a video of known axial steps (the paper's test 2, from rest) and its "
                   "stage log with a dz_mm column (docs/sensor.md section 7); repeatable; "
                   "fixes the scale with or without --square-side-mm")  # fmt: skip
    p.add_argument("--out", required=True, metavar="BUILD.toml", help="fitted sensor file")
    p.add_argument("--chessboard", metavar="DIR",
                   help="folder of chessboard images: intrinsics from them, held")  # fmt: skip
    p.add_argument("--pattern", default="9x6", metavar="CxR",
                   help="inner corners of the chessboard (default 9x6)")  # fmt: skip
    p.add_argument(
        "--square-mm",
        type=float,
        default=1.0,
        metavar="S",
        help="chessboard square size (mm; does not enter the intrinsics)",
    )
    p.add_argument("--rounds", type=int, default=MAX_ROUNDS,
                   help="rounds of tracking and adjustment at most; they stop once the fit "
                   "is stable (default %(default)s)")  # fmt: skip
    features_arg(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_run_calibrate_sensor)


def _pattern(text: str) -> tuple[int, int]:
    try:
        cols, rows = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise CommandError(f"--pattern must be like 9x6, got {text!r}") from None
    if cols < 2 or rows < 2:
        raise CommandError(f"--pattern needs at least 2x2 inner corners, got {text!r}")
    return cols, rows


def _chessboard(args, sensor):
    from camwhisker.calibration.sweep import intrinsics_from_chessboard

    folder = Path(args.chessboard)
    if not folder.is_dir():
        raise CommandError(f"--chessboard {folder}: not a folder")
    images = sorted(f for f in folder.iterdir() if f.suffix.lower() in _IMAGE_SUFFIXES)
    cam = sensor.camera
    intrinsics, rms = intrinsics_from_chessboard(images, _pattern(args.pattern), args.square_mm,
                                                 (cam.width_px, cam.height_px))  # fmt: skip
    print(f"chessboard: {len(images)} images, reprojection RMS {rms:.3f} px")
    return intrinsics


def _run_calibrate_sensor(args) -> int:
    from tqdm import tqdm

    from camwhisker.calibration.report import write_sensor_fit
    from camwhisker.calibration.sweep import calibrate_sensor
    from camwhisker.contact.stage import read_stage_log
    from camwhisker.io.sources import check_frame_size, open_source
    from camwhisker.sensor.file import load_sensor
    from camwhisker.vision.tracker import FrontEndOptions

    if args.rounds < 1:
        raise CommandError(f"--rounds must be >= 1, got {args.rounds}")
    if args.square_side_mm is None and not args.dz_steps:
        raise CommandError("give --square-side-mm or --dz-steps VIDEO LOG: the images alone "
                           "do not fix the scale")  # fmt: skip
    dz_steps = [(video, read_stage_log(log)) for video, log in args.dz_steps]
    sensor = load_sensor(args.sensor)
    intrinsics = _chessboard(args, sensor) if args.chessboard else None
    options = FrontEndOptions(features=feature_hints(args, sensor))
    sources = [open_source(v) for v in [*args.videos, *(v for v, _ in dz_steps)]]
    for source in sources:
        check_frame_size(source, sensor)
    n_frames = sum(len(s) for s in sources)
    bar = tqdm(total=n_frames * args.rounds, unit="frame", desc="calibrate-sensor round 1",
               disable=args.quiet)  # fmt: skip

    def on_round(k, adj):
        if k + 1 < args.rounds:
            bar.set_description(f"calibrate-sensor round {k + 2}")
        bar.write(f"round {k + 1}: residual {adj.sigma_px:.3f} px, {int(adj.used.sum())} "
                  f"frames, held {len(adj.held)}")  # fmt: skip

    try:
        cal = calibrate_sensor(args.videos, sensor, args.square_side_mm, intrinsics,
                               args.rounds, bar.update, on_round, options, dz_steps)  # fmt: skip
        # The fit may settle before the last round: the bar ends where the work did.
        bar.set_description(f"calibrate-sensor, {len(cal.ok_fraction)} rounds")
        bar.total = bar.n
        bar.refresh()
    finally:
        bar.close()
    inputs = {"videos": [str(v) for v in args.videos], "square_side_mm": args.square_side_mm,
              "dz_steps": [{"video": v, "stage_log": log} for v, log in args.dz_steps],
              "chessboard": args.chessboard, "intrinsics_from_chessboard": intrinsics,
              "features": args.features}  # fmt: skip
    paths = write_sensor_fit(cal, sensor, args.out, inputs, command_line(args))
    adj = cal.adjustment
    print(f"{len(cal.ok_fraction)} rounds; ok rows {100 * cal.ok_fraction[0]:.1f} % with the "
          f"starting file, {100 * cal.ok_fraction[-1]:.1f} % with the fit; residual "
          f"{adj.sigma_px:.3f} px; phi at 20 deg read with the fit: SE "
          f"{adj.phi_se_deg():.3f} deg")  # fmt: skip
    print(adj.dz_scale.text())
    for warning in adj.warnings:
        print(f"camwhisker calibrate-sensor: warning: {warning}", file=sys.stderr)
    for path in paths.values():
        print(f"wrote {path}")
    return 0
