"""``camwhisker dev``: the 3-D simulators of taps and whisks, and the benchmark scripts as
``camwhisker dev NAME-bench`` (each parses its own options)."""

from __future__ import annotations

import argparse
import importlib

__all__ = ["BENCH_SCRIPTS", "add_bench_scripts", "add_simulate_taps", "add_simulate_whisk"]

#: ``camwhisker dev NAME-bench`` -> (module under camwhisker.bench, what it measures).
BENCH_SCRIPTS = {
    "vision-bench": ("vision", "front end: speed and accuracy, exact model beside paper mode"),
    "reality-bench": ("reality", "front end on hand-made builds, true and nominal sensor file"),
    "systematics-bench": ("systematics", "where a calibration's error comes from"),
    "calibration-bench": ("calibration", "calibrate-sensor on held-out builds"),
    "subpixel-bench": ("subpixel", "the corners' sub-pixel bias: the LK alone, then per codec"),
    "throughput-bench": ("throughput", "batch frames/s with 1 worker against 2"),
    "batch-bench": ("batch_read", "a batch against OpenCV's decode-only read, one core"),
    "live-bench": ("live", "the front end's time per 720p frame on one core"),
    "view-bench": ("view", "the live loop's latency with the browser view open and without"),
    "belief-bench": ("belief", "contact belief on rendered video: onset error, false contacts"),
    "filmed-frames-bench": ("filmed_frames", "per-frame contact on filmed sweeps"),
    "texture-bench": ("texture", "smallest gap and amplitude resolved, per frame rate"),
    "learn-bench": ("learn", "the learned estimator: architecture, training, inference"),
    "solids-bench": ("solids", "objects in 3-D from sweeps lifted into space"),
    "space-filmed-bench": ("space_filmed", "a sweep in space filmed: contact points, object"),
    "taps-bench": ("taps", "seed 000's spheres and plane tapped by a rig: identification, error"),
    "whisk-bench": ("whisk", "a base that turns: contact points with and without its model"),
}


def add_simulate_taps(sub) -> None:
    p = sub.add_parser("simulate-taps",
                       help="taps in 3-D on a sphere, a plate or a cylinder: signal tables, pose "
                            "logs and the true contact points, with the object")
    p.add_argument("--object", required=True, choices=("sphere", "plane", "cylinder"),
                   help="a sphere or a plate tapped by a rig of five sensors; a cylinder tapped "
                        "six times with the shaft across its axis")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder for NAME.signals.csv, NAME.pose.csv, NAME.contact_truth.csv "
                        "and object.json (the object in W, the true clock offsets)")
    p.add_argument("--seed", type=int, default=0, help="seed of the object and the taps")
    p.set_defaults(func=_run_simulate_taps)


def _run_simulate_taps(args: argparse.Namespace) -> int:
    from camwhisker.cli.common import command_line
    from camwhisker.sim.mechanics.taps import write_object_taps

    paths = write_object_taps(args.out, args.object, args.seed, command_line(args))
    print(f"wrote {len(paths)} files to {args.out} (object.json: the object and the offsets)")
    return 0


def add_simulate_whisk(sub) -> None:
    p = sub.add_parser("simulate-whisk",
                       help="a base that turns (a wrist, a whisking actuator) against a wall or "
                            "a cylinder: signal table, pose log and the true contact point")
    p.add_argument("--kind", required=True, choices=("wall", "cylinder"),
                   help="a wall holds the contact stuck; a cylinder lets it roll a little")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder for NAME.signals.csv, NAME.pose.csv (on its own clock) and "
                        "NAME.truth.csv (the true contact in W, camera clock)")
    p.add_argument("--seed", type=int, default=0, help="seed of the object and the whisk")
    p.set_defaults(func=_run_simulate_whisk)


def _run_simulate_whisk(args: argparse.Namespace) -> int:
    from camwhisker.sim.mechanics.whisk import write_whisk

    run = write_whisk(args.out, args.kind, args.seed)
    print(f"wrote {run.name}.signals.csv, .pose.csv and .truth.csv to {args.out}; the pose "
          f"clock's true offset: {run.offset_s:+.4f} s (t_camera = t_pose + offset)")
    return 0


def add_bench_scripts(sub) -> None:
    for name, (module, what) in BENCH_SCRIPTS.items():
        p = sub.add_parser(name, help=what, add_help=False,
                           description=f"{what}. Options: `camwhisker dev {name} -h`.")
        p.set_defaults(func=_run_script, passes_options=True, module=module)


def _run_script(args: argparse.Namespace) -> int:
    script = importlib.import_module(f"camwhisker.bench.{args.module}")
    return int(script.main(args.argv) or 0)
