"""experiment: a folder of the user's recordings -> signals, calibration, contacts, objects."""

from __future__ import annotations

import sys

from camwhisker.cli.common import command_line, sensor_arg

__all__ = ["add_experiment"]


def add_experiment(sub) -> None:
    p = sub.add_parser(
        "experiment",
        help="a folder of recordings (NAME.mp4 + NAME.stage.csv or NAME.pose.csv) -> "
        "batch, calibrate, contact, percepts and plots",
        description="Runs batch on every video, calibrate on the runs whose stage log has "
        "an r_mm column, contact on every run and percept on every other run, with the "
        "plots. Finished signal tables are reused when run again.",
    )
    p.add_argument("folder", help="per run NAME.mp4 or NAME.avi with NAME.stage.csv "
                   "(docs/sensor.md section 7) or NAME.pose.csv (section 9), and "
                   "sensor.toml; a rig's: rig.toml, the carrier's RUN.pose.csv, and per "
                   "sensor a folder SENSOR/ with its videos and calibration runs")  # fmt: skip
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder for signals/, calib.toml, contact/, percept/, the figures "
                   "and summary.json (a rig: those of each sensor in SENSOR/; one "
                   "percept/space.json and map)")  # fmt: skip
    sensor_arg(p, "sensor file (TOML); default: the folder's sensor.toml")
    p.add_argument("--per", choices=("pause", "frame"), default="pause",
                   help="contact from the medians of each stage pause, as the paper "
                   "(default), or from every frame")  # fmt: skip
    p.add_argument("--mount", metavar="X,Y,Z,QW,QX,QY,QZ",
                   help="where the pose logs give a carrier's pose (a robot's flange): the "
                        "sensor's pose in the carrier's frame (docs/sensor.md section 9)")
    p.add_argument("--rig", metavar="RIG.toml",
                   help="a rig of several sensors on one carrier (default: the folder's "
                        "rig.toml where it has one): the sensors, each with its mount, its "
                        "recordings in FOLDER/SENSOR/ and the carrier's FOLDER/RUN.pose.csv")
    p.add_argument("--jobs", type=int, default=2, help="videos processed in parallel")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run_experiment)


def _run_experiment(args) -> int:
    from camwhisker.io.poses import Mount
    from camwhisker.run.experiment import format_experiment, run_experiment
    from camwhisker.run.workers import stop_signals_interrupt

    mount = Mount.parse(args.mount) if args.mount else None
    with stop_signals_interrupt():  # SIGTERM unwinds as Ctrl-C does: no temporary file left
        summary = run_experiment(args.folder, args.out, sensor=args.sensor, jobs=args.jobs,
                                 per=args.per, progress=not args.quiet,
                                 command=command_line(args), mount=mount,
                                 rig=args.rig)  # fmt: skip
    print(format_experiment(summary))
    if "rig" in summary:
        print(f"wrote {args.out}/summary.json, percept/, map.* and per sensor SENSOR/ "
              "(calib.toml, signals/, contact/, percept/, fig7a_gm_model.png)")
    else:
        print(f"wrote {args.out}/summary.json, calib.toml, signals/, contact/, percept/ and "
              "fig7a_gm_model.png")
    for name, why in summary["failed"].items():
        print(f"camwhisker experiment: problem: {name}: {why}", file=sys.stderr)
    return 1 if summary["failed"] else 0
