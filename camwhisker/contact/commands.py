"""The contact back end's commands (wiring only; registered by :mod:`camwhisker.cli`).

simulate-stage, calibrate, contact (SENSOR.md section 7) and contact-bench.
Input problems (ValueError subclasses naming file, row, key) are re-raised as
the CLI's error class, so they print without a traceback.
"""

from __future__ import annotations

import math
import shlex
import sys
from pathlib import Path

__all__ = ["add_commands"]


def _command_line(args) -> str:
    """The command as parsed (also right when main() is called with an argv list)."""
    parts = ["camwhisker", args.command]
    for key, value in vars(args).items():
        if key in ("command", "func") or value is None:
            continue
        flag = "--" + key.replace("_", "-")
        for v in value if isinstance(value, list) else [value]:
            parts += [flag, str(v)]
    return " ".join(shlex.quote(p) for p in parts)


def _guard(run, error_cls):
    def wrapped(args):
        try:
            return run(args)
        except ValueError as exc:  # StageLogError, SignalTableError, CalibrationError, ...
            raise error_cls(str(exc)) from exc

    return wrapped


def _l_w(args) -> tuple[float, str]:
    from camwhisker.sensor import load_sensor

    sensor = load_sensor(args.sensor)
    return sensor.whisker.length_mm, sensor.source


def _run_simulate(args) -> int:
    from camwhisker.mechanics import NoiseModel, WhiskerMechanics, simulate_runs
    from camwhisker.mechanics.files import write_runs

    l_w, _ = _l_w(args)
    noise = NoiseModel(phi_deg=args.noise_phi_deg, dz_mm=args.noise_dz_mm)
    runs = simulate_runs(args.kind, args.seed, mech=WhiskerMechanics(length_mm=l_w), noise=noise)
    manifest = write_runs(runs, args.out, args.seed, _command_line(args))
    for run in runs:
        print(f"{run.name}: {run.info['n_steps']} steps, offset {run.offset_s:+.3f} s, "
              f"{run.signals['t_s'].size} frames")
    print(f"wrote {len(runs)} run(s) to {args.out} ({manifest.name})")
    return 0


def _run_calibrate(args) -> int:
    from camwhisker.calibrate import (
        MF_MAX_SPREAD_MM,
        CalibrationRun,
        calibrate,
        write_calibration,
    )
    from camwhisker.signals import read_signal_table
    from camwhisker.stage import read_stage_log

    if len(args.signals) != len(args.stage):
        raise ValueError(f"give one --stage per --signals ({len(args.signals)} signals, "
                         f"{len(args.stage)} stage logs)")
    offsets = args.offset_s or [None] * len(args.signals)
    if len(offsets) != len(args.signals):
        raise ValueError("give --offset-s for every run or for none")
    l_w, sensor_source = _l_w(args)
    runs = [CalibrationRun(read_signal_table(s), read_stage_log(g), str(s), o)
            for s, g, o in zip(args.signals, args.stage, offsets, strict=True)]
    calib, analyses, data = calibrate(runs, l_w, sensor_source, _command_line(args))
    write_calibration(args.out, calib)
    for run, a in zip(runs, analyses, strict=True):
        how = "estimated" if a.offset_estimated else "given"
        print(f"{run.log.source}: offset {a.offset_s:+.3f} s ({how}), "
              f"{int((a.dx_mm == a.dx_mm).sum())} contact pauses")
    eq8 = calib.gm.alternatives["eq8"]
    lo, hi = eq8.ci["c"]
    print(f"eq. (8): C = {eq8.params['c']:.2f} (95 % CI {lo:.2f}-{hi:.2f}), "
          f"RMSE {eq8.rmse_mm:.2f} mm; GM model used: {calib.gm.kind} "
          f"(RMSE {calib.gm.rmse_mm:.2f} mm)")
    floor = calib.mf_table.phi_min_deg
    if math.isinf(floor):
        print(f"warning: MF's scatter from noise exceeds {MF_MAX_SPREAD_MM:g} mm at every phi: "
              "MF, z_score and the fusion will be empty (calibrate with more runs, or with "
              "less noise)", file=sys.stderr)
    else:
        print(f"MF: {len(calib.mf_table)} table points from {len(runs)} run(s), estimates "
              f"from phi >= {floor:g} deg")
    if args.plots:
        from camwhisker.contact.plots import plot_gm_model

        path = Path(args.plots) / "gm_model.png"
        plot_gm_model(calib, data, path, f"Fig. 7A from {_command_line(args)}")
        print(f"wrote {path}")
    print(f"wrote {args.out}")
    return 0


def _run_contact(args) -> int:
    from camwhisker.calibrate import read_calibration
    from camwhisker.contact.pipeline import contact_rows
    from camwhisker.signals import read_signal_table
    from camwhisker.stage import read_stage_log
    from camwhisker.tables import write_csv

    calib = read_calibration(args.calib)
    signals = read_signal_table(args.signals)
    cols, run = contact_rows(signals, read_stage_log(args.stage), calib, args.offset_s)
    write_csv(args.out, cols)
    defined = int((cols["r_hat_mm"] == cols["r_hat_mm"]).sum())
    print(f"offset {run.offset_s:+.3f} s ({'estimated' if run.offset_estimated else 'given'}), "
          f"first contact at x = {run.x_contact_mm:.2f} mm; {defined} of "
          f"{cols['t_s'].size} rows with an estimate; wrote {args.out}")
    return 0


def _run_bench(args) -> int:
    from camwhisker.contact.bench import format_report, run_bench

    result = run_bench(args.seed, figures_dir=args.figures, n_timing=args.samples)
    print(format_report(result))
    if args.figures:
        print(f"wrote figures to {args.figures}")
    return 0


def add_commands(sub, error_cls) -> None:
    """Register the contact back end's subcommands on an argparse subparsers object."""
    from camwhisker.mechanics.experiment import (
        FRONT_END_NOISE_DZ_MM,
        FRONT_END_NOISE_PHI_DEG,
        KINDS,
        PAPER_NOISE_DZ_MM,
        PAPER_NOISE_PHI_DEG,
    )

    p = sub.add_parser("simulate-stage", help="simulate a stage experiment (mechanics) to files")
    p.add_argument("--kind", required=True, choices=KINDS)
    p.add_argument("--out", required=True, metavar="DIR")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--noise-phi-deg", type=float, default=PAPER_NOISE_PHI_DEG,
                   help=f"per-frame phi noise (default: the paper's; our front end's target: "
                        f"{FRONT_END_NOISE_PHI_DEG})")
    p.add_argument("--noise-dz-mm", type=float, default=PAPER_NOISE_DZ_MM,
                   help=f"per-frame dz noise (default: the paper's; our front end's target: "
                        f"{FRONT_END_NOISE_DZ_MM})")
    p.add_argument("--sensor", metavar="FILE", help="sensor file (whisker length)")
    p.set_defaults(func=_guard(_run_simulate, error_cls))

    p = sub.add_parser("calibrate", help="fit GM (eq. 8), sigma_GM and the MF table")
    p.add_argument("--signals", action="append", required=True, metavar="S.csv")
    p.add_argument("--stage", action="append", required=True, metavar="L.csv")
    p.add_argument("--offset-s", action="append", type=float,
                   help="known clock offset per run (t_camera = t_stage + offset); "
                        "default: estimated")
    p.add_argument("--sensor", metavar="FILE", help="sensor file (whisker length)")
    p.add_argument("--out", required=True, metavar="CALIB")
    p.add_argument("--plots", metavar="DIR", help="also write gm_model.png (Fig. 7A) here")
    p.set_defaults(func=_guard(_run_calibrate, error_cls))

    p = sub.add_parser("contact", help="contact distance and shape per signal row")
    p.add_argument("--signals", required=True, metavar="S.csv")
    p.add_argument("--stage", required=True, metavar="L.csv")
    p.add_argument("--calib", required=True, metavar="CALIB")
    p.add_argument("--offset-s", type=float, help="known clock offset; default: estimated")
    p.add_argument("--out", required=True, metavar="C.csv")
    p.set_defaults(func=_guard(_run_contact, error_cls))

    p = sub.add_parser("contact-bench",
                       help="speed and error of the contact back end on simulated runs, "
                            "at the paper's noise and at our front end's")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--samples", type=int, default=100_000, help="samples for the timing")
    p.add_argument("--figures", metavar="DIR", help="write Fig. 8 and Fig. 9 style PNGs here")
    p.set_defaults(func=_guard(_run_bench, error_cls))
