"""The contact back end: simulate-stage, calibrate, contact (docs/sensor.md section 7)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

from camwhisker.cli.common import (
    CommandError,
    command_line,
    paired_runs,
    runs_arg,
    sensor_arg,
    springs_arg,
    springs_of,
)
from camwhisker.sensor.file import load_sensor

__all__ = ["add_simulate_space", "add_simulate_stage", "add_calibrate", "add_contact"]

_SENSOR_HELP = "sensor file, for the whisker's length; default: Table I values"


def add_simulate_stage(sub) -> None:
    from camwhisker.sim.mechanics.experiment import (
        FRONT_END_NOISE_DZ_MM,
        FRONT_END_NOISE_PHI_DEG,
        KINDS,
        PAPER_NOISE_DZ_MM,
        PAPER_NOISE_PHI_DEG,
    )

    p = sub.add_parser("simulate-stage", help="simulate a stage experiment (mechanics) to files")
    p.add_argument("--kind", required=True, choices=KINDS,
                   help="test1 and test2: the paper's accuracy tests, for `camwhisker validate`")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder for the signal tables, stage logs and truth of every run")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulation")
    p.add_argument("--noise-phi-deg", type=float, default=PAPER_NOISE_PHI_DEG,
                   help=f"per-frame phi noise (default: the paper's; our front end's target: "
                        f"{FRONT_END_NOISE_PHI_DEG})")
    p.add_argument("--noise-dz-mm", type=float, default=PAPER_NOISE_DZ_MM,
                   help=f"per-frame dz noise (default: the paper's; our front end's target: "
                        f"{FRONT_END_NOISE_DZ_MM})")
    p.add_argument("--speed-mm-s", type=float, metavar="V",
                   help="sweep at this constant base speed without pausing (a rest before "
                        "and after only); default: the paper's 1 mm steps with >= 1 s pauses")
    sensor_arg(p, _SENSOR_HELP)
    p.add_argument("--springs", metavar="FILE",
                   help="test1 and test2: the suspension's stiffness behind the simulated "
                        "force log (<run>_forces.csv); default: the spring model of Table I")
    p.set_defaults(func=_run_simulate)


def _run_simulate(args) -> int:
    from camwhisker.sensor.springs import suspension_stiffness
    from camwhisker.sim.mechanics import NoiseModel, WhiskerMechanics, simulate_runs
    from camwhisker.sim.mechanics.files import write_runs
    from camwhisker.sim.mechanics.ftsensor import FORCE_KINDS, simulate_force_logs

    l_w = load_sensor(args.sensor).whisker.length_mm
    noise = NoiseModel(phi_deg=args.noise_phi_deg, dz_mm=args.noise_dz_mm)
    sim = {}
    if args.speed_mm_s is not None:
        from camwhisker.sim.mechanics.experiment import continuous_protocol

        if args.kind in FORCE_KINDS:
            raise CommandError(f"--speed-mm-s: {args.kind} follows the paper's stepped protocol")
        if not args.speed_mm_s > 0:
            raise CommandError(f"--speed-mm-s: must be positive, got {args.speed_mm_s:g}")
        sim["protocol"] = continuous_protocol(args.speed_mm_s)
    runs = simulate_runs(args.kind, args.seed, mech=WhiskerMechanics(length_mm=l_w), noise=noise,
                         **sim)
    force_logs = None
    if args.kind in FORCE_KINDS:
        stiffness = springs_of(args) or suspension_stiffness()
        force_logs = simulate_force_logs(runs, stiffness, args.seed)
    elif args.springs:
        raise CommandError(f"--springs: only {' and '.join(FORCE_KINDS)} write a force log")
    manifest = write_runs(runs, args.out, args.seed, command_line(args), force_logs)
    for run in runs:
        print(f"{run.name}: {run.info['n_steps']} steps, offset {run.offset_s:+.3f} s, "
              f"{run.signals['t_s'].size} frames")
    print(f"wrote {len(runs)} run(s) to {args.out} ({manifest.name})")
    return 0


def add_simulate_space(sub) -> None:
    p = sub.add_parser("simulate-space",
                       help="a wall or a cylinder swept at three heights, its runs as signal "
                            "tables and pose logs in a turned world frame, with the truth")
    p.add_argument("--kind", required=True, choices=("wall", "cylinder"),
                   help="a wall is a plane in space, a cylinder's axis is across the sweeps")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder for NAME.signals.csv, NAME.pose.csv and object.json (the "
                        "object in the world frame, the true clock offsets)")
    p.add_argument("--seed", type=int, default=0, help="seed of the object and the runs")
    p.add_argument("--rig", action="store_true",
                   help="the heights as three sensors on one carrier: rig.toml, the carrier's "
                        "RUN.pose.csv, SENSOR/RUN.signals.csv")  # fmt: skip
    p.set_defaults(func=_run_simulate_space)


def _run_simulate_space(args) -> int:
    from camwhisker.sim.mechanics.space import write_space_sweep

    paths = write_space_sweep(args.out, args.kind, args.seed, command_line(args), rig=args.rig)
    print(f"wrote {len(paths)} files to {args.out} (object.json: the object and the offsets)")
    return 0


def add_calibrate(sub) -> None:
    p = sub.add_parser("calibrate", help="fit GM (eq. 8), sigma_GM and the MF table")
    runs_arg(p, "calibration run")
    p.add_argument("--offset-s", action="append", type=float,
                   help="known clock offset per run (t_camera = t_stage + offset); "
                        "default: estimated")
    sensor_arg(p, _SENSOR_HELP)
    p.add_argument("--out", required=True, metavar="CALIB",
                   help="calibration file to write (TOML; CALIB.mf.csv beside it)")
    p.add_argument("--plots", metavar="DIR", help="also write gm_model.png (Fig. 7A) here")
    p.set_defaults(func=_run_calibrate)


def _run_calibrate(args) -> int:
    from camwhisker.contact.calibrate import (
        CalibrationRun,
        calibrate,
        format_calibration,
        write_calibration,
    )
    from camwhisker.contact.stage import read_stage_log
    from camwhisker.io.signals import read_signal_table

    pairs = paired_runs(args, "offset_s")
    sensor = load_sensor(args.sensor)
    runs = [CalibrationRun(read_signal_table(s), read_stage_log(g), str(s), o)
            for s, g, o in pairs]
    calib, analyses, data = calibrate(runs, sensor.whisker.length_mm, sensor.source,
                                      command_line(args))
    write_calibration(args.out, calib)
    lines, warning = format_calibration(runs, analyses, calib)
    print("\n".join(lines))
    if warning is not None:
        print(f"warning: {warning}", file=sys.stderr)
    if args.plots:
        from camwhisker.contact.plots import plot_gm_model

        path = Path(args.plots) / "gm_model.png"
        plot_gm_model(calib, data, path, f"Fig. 7A from {command_line(args)}")
        print(f"wrote {path}")
    print(f"wrote {args.out}")
    return 0


def add_contact(sub) -> None:
    p = sub.add_parser("contact", help="contact distance and shape per signal row")
    p.add_argument("--signals", required=True, metavar="S.csv",
                   help="the run's signal table (batch, live or replay)")
    base = p.add_mutually_exclusive_group(required=True)
    base.add_argument("--stage", metavar="L.csv",
                      help="the run's stage log (t_s, x_mm on the stage's clock)")
    base.add_argument("--pose", metavar="P.csv",
                      help="the run's pose log instead (t_s, x_mm, y_mm, z_mm, qw, qx, qy, qz "
                           "on its own clock, docs/sensor.md section 9): adds the contact "
                           "point px_mm, py_mm, pz_mm and the normal nx, ny, nz in its frame")
    p.add_argument("--mount", metavar="X,Y,Z,QW,QX,QY,QZ",
                   help="with --pose, where the log gives a carrier's pose (a robot's "
                        "flange): the sensor's pose in the carrier's frame")
    p.add_argument("--calib", required=True, metavar="CALIB",
                   help="calibration file written by camwhisker calibrate")
    p.add_argument("--offset-s", type=float,
                   help="known clock offset (t_camera = t_stage + offset); default: estimated")
    p.add_argument("--per", choices=("frame", "pause"), default="frame",
                   help="estimates from each frame (default; moving or paused) or, as in the "
                        "paper, from the medians of the stage pause the frame lies in")
    p.add_argument("--out", required=True, metavar="C.csv",
                   help="contact table to write, one row per signal row")
    p.add_argument("--learned", metavar="MODEL",
                   help="also a learned estimator's r (docs/learn.md, 'On this sensor') as "
                        "the column r_learned_mm; the fusion does not use it. A network "
                        "model (learn --kind conv) needs torch")
    springs_arg(p)
    p.set_defaults(func=_run_contact)


def _run_contact(args) -> int:
    from camwhisker.contact.calibrate import read_calibration
    from camwhisker.contact.pipeline import contact_rows
    from camwhisker.contact.stage import read_stage_log
    from camwhisker.files.tables import write_csv
    from camwhisker.io.signals import read_signal_table

    calib = read_calibration(args.calib)
    signals = read_signal_table(args.signals)
    springs = springs_of(args)
    model = None
    if args.learned:
        from camwhisker.learn.modeldir import load_model

        model = load_model(args.learned)  # before any work: a bad model is named first
    if args.mount and not args.pose:
        raise CommandError("--mount goes with --pose (a carrier's pose log)")
    if args.pose:
        from camwhisker.contact.space import contact_rows_in_space
        from camwhisker.io.poses import Mount, read_pose_log

        poses = read_pose_log(args.pose, Mount.parse(args.mount) if args.mount else None)
        cols, run, theta = contact_rows_in_space(signals, poses, calib, args.offset_s,
                                                 mode=args.per)  # fmt: skip
        print(f"the base pressed toward theta {theta:.1f} deg")
        from camwhisker.contact.space import STILL_TURN_DEG

        if poses.turn_deg() > STILL_TURN_DEG:
            print(f"the base turns by {poses.turn_deg():.1f} deg: the travel is the shaft's "
                  "point's at the contact's r, solved for")
    else:
        cols, run = contact_rows(signals, read_stage_log(args.stage), calib, args.offset_s,
                                 mode=args.per)  # fmt: skip
    if model is not None:
        from camwhisker.learn.sensor import learned_r_mm

        cols["r_learned_mm"] = learned_r_mm(model, cols, signals["theta_deg"], args.learned)
    if springs is not None:
        cols.update(springs.columns(cols["dz_mm"], cols["phi_deg"]))
    write_csv(args.out, cols)
    defined = int((cols["r_hat_mm"] == cols["r_hat_mm"]).sum())
    onset = (f"first contact at x = {run.x_contact_mm:.2f} mm"
             if run.x_contact_mm == run.x_contact_mm else "no contact found")
    how = "given"
    if run.offset_estimated and run.paused:
        how = "estimated from pauses"
    elif run.offset_estimated and math.isfinite(run.offset_se_s):
        how = f"estimated from motion, se {run.offset_se_s:.3f} s"
    elif run.offset_estimated:
        how = ("estimated from motion, not pinned: the base changes speed only out of contact; "
               "any offset moves every x alike, and GM's travel not at all")
    print(f"offset {run.offset_s:+.3f} s ({how}), "
          f"{onset}; {defined} of {cols['t_s'].size} rows with an estimate (per {args.per}); "
          f"wrote {args.out}")
    if defined == 0:
        print(f"camwhisker contact: problem: {args.signals}: no row has a contact estimate "
              f"({onset} in {args.stage or args.pose})", file=sys.stderr)
        return 1
    return 0
