"""Synthetic data: render, bound, make-samples, describe, make-experiment."""

from __future__ import annotations

import sys

from camwhisker.cli.common import CommandError, command_line, sensor_arg
from camwhisker.sensor.file import load_sensor

__all__ = ["add_render", "add_bound", "add_samples", "add_describe", "add_experiment"]


def add_render(sub) -> None:
    from camwhisker.sim.render.scenarios import SCENARIOS

    p = sub.add_parser("render", help="render a synthetic scenario to video with its truth")
    p.add_argument("scenario", choices=sorted(SCENARIOS), help="what to render")
    p.add_argument("--out", required=True, metavar="VIDEO", help="output .avi (MJPG) or .mp4")
    p.add_argument("--frames", type=int, default=60, metavar="N", help="frames to render")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the scenario's noise and artefacts (same seed, same video)")
    p.add_argument("--fps", type=float, default=30.0, help="the video's frame rate")
    p.add_argument(
        "--build",
        type=int,
        metavar="SEED",
        help="draw hand-made build SEED from the sensor file (its true file is written "
        "beside the truth, its description in the .json)",
    )
    sensor_arg(p)
    p.set_defaults(func=_run_render)


def _run_render(args) -> int:
    from camwhisker.sim.render.scenarios import make_scenario
    from camwhisker.sim.render.video import render_scenario

    scenario = make_scenario(args.scenario, args.frames, args.seed, args.fps)
    sensor = load_sensor(args.sensor)
    build = None
    if args.build is not None:
        from camwhisker.sim.render.builds import draw_build

        build = draw_build(args.build, sensor)
    paths = render_scenario(scenario, sensor, args.out, args.seed, True, build)
    for kind, path in paths.items():
        print(f"{kind:>6}: {path}")
    return 0


def add_bound(sub) -> None:
    from camwhisker.sim.render.scenarios import SCENARIOS

    p = sub.add_parser("bound", help="Cramér-Rao bound on dz, phi, theta for a scene")
    p.add_argument(
        "--scenario",
        default="nominal",
        choices=sorted(SCENARIOS),
        help="whose camera and artefacts to use",
    )
    p.add_argument("--dz-mm", type=float, default=0.5, help="the pose's axial deflection (mm)")
    p.add_argument("--phi-deg", type=float, default=15.0, help="the pose's tilt (deg)")
    p.add_argument("--theta-deg", type=float, default=30.0, help="the tilt's direction (deg)")
    p.add_argument("--with-shift", action="store_true", help="estimate sx, sy as nuisances too")
    sensor_arg(p)
    p.set_defaults(func=_run_bound)


def _run_bound(args) -> int:
    from camwhisker.sensor.plate import Pose
    from camwhisker.sim.render.bound import pose_bound
    from camwhisker.sim.render.scenarios import make_scenario

    scenario = make_scenario(args.scenario, 30, 0)  # only its camera is used
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


def add_samples(sub) -> None:
    p = sub.add_parser("make-samples", help="regenerate the bundled sample videos and build")
    p.add_argument("--dest", default="sample_frames", metavar="DIR",
                   help="folder to write the samples into")
    p.set_defaults(func=_run_samples)


def _run_samples(args) -> int:
    from camwhisker.sim.render.samples import make_samples

    for path in make_samples(args.dest):
        print(path)
    return 0


def add_describe(sub) -> None:
    p = sub.add_parser("describe", help="decode a video and summarise it and its truth")
    p.add_argument("video", help="a video file (its truth V.truth.csv is read where it is "
                   "beside it)")
    p.add_argument(
        "--signals",
        metavar="S.csv",
        help="its signal table (batch): ok rows, phi and dz RMSE against the truth",
    )
    p.set_defaults(func=_run_describe)


def _run_describe(args) -> int:
    from camwhisker.sim.render.samples import describe_video

    info = describe_video(args.video, args.signals)
    for key, value in info.items():
        if key != "warning":
            print(f"{key:>19}: {_plain(value)}")
    if "warning" in info:
        print(f"camwhisker dev describe: warning: {info['warning']}", file=sys.stderr)
        return 1
    return 0


def _plain(value) -> str:
    """A number to 6 significant digits, a range as 'lo to hi', anything else as it is."""
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, tuple):
        return " to ".join(_plain(v) for v in value)
    return str(value)


def add_experiment(sub) -> None:
    p = sub.add_parser(
        "make-experiment",
        help="simulate a stage experiment and film it (videos, stage logs, truth)",
    )
    p.add_argument("--dest", default="sample_frames/experiment", metavar="DIR",
                   help="folder to write the videos, stage logs and truth into")
    p.add_argument("--seed", type=int, default=8, help="seed of the simulation and the renders")
    p.add_argument("--jobs", type=int, default=2, help="runs rendered in parallel")
    p.set_defaults(func=_run_experiment)


def add_space_experiment(sub) -> None:
    p = sub.add_parser(
        "make-space-experiment",
        help="a wall or cylinder swept in space and its calibration, filmed: a folder for "
             "camwhisker experiment (videos, stage and pose logs, sensor.toml, truth)",
    )
    p.add_argument("--kind", required=True, choices=("wall", "cylinder"),
                   help="the object swept at three heights")
    p.add_argument("--dest", required=True, metavar="DIR", help="folder to write into")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulation and the renders")
    p.add_argument("--jobs", type=int, default=2, help="runs rendered in parallel")
    p.add_argument("--rig", action="store_true",
                   help="the three heights as three sensors on one carrier: rig.toml, one "
                        "carrier pose log per run, a folder per sensor with its videos and "
                        "calibration runs (one set of films, linked into each folder: the "
                        "simulated sensors are one build)")
    p.add_argument("--own-calibration-films", action="store_true",
                   help="with --rig: film each sensor's calibration runs apart (three times "
                        "the calibration's rendering)")  # fmt: skip
    p.set_defaults(func=_run_space_experiment)


def _run_space_experiment(args) -> int:
    from camwhisker.sim.render.space import render_space_experiment

    if args.own_calibration_films and not args.rig:
        raise CommandError("--own-calibration-films: only with --rig (a folder per sensor)")
    print(render_space_experiment(args.dest, args.kind, args.seed, jobs=args.jobs,
                                  command=command_line(args), rig=args.rig,
                                  own_calibration_films=args.own_calibration_films))  # fmt: skip
    return 0


def _run_experiment(args) -> int:
    from camwhisker.sim.render.experiment import render_experiment

    print(render_experiment(args.dest, args.seed, jobs=args.jobs))
    return 0
