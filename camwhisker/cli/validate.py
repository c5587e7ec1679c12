"""validate: the paper's accuracy tests (Fig. 6 A/B) from a signal table and a stage log."""

from __future__ import annotations

from camwhisker.cli.common import (
    CommandError,
    command_line,
    paired_runs,
    runs_arg,
    sensor_arg,
    springs_of,
)
from camwhisker.sensor.file import load_sensor

__all__ = ["add_validate"]


def add_validate(sub) -> None:
    p = sub.add_parser("validate", help="applied against measured phi (test 1) or dz (test 2), "
                                        "RMSE and the plot of Fig. 6 A/B")
    runs_arg(p, "trial")
    p.add_argument("--test", required=True, type=int, choices=(1, 2),
                   help="1: rigid whisker stepped at a known r (phi; the stage logs need r_mm); "
                        "2: known dz steps (the stage logs need dz_mm)")
    sensor_arg(p, "sensor file the signals were made with (recorded in the summary)")
    p.add_argument("--clock-offset-s", type=float, action="append",
                   help="known clock offset per trial (t_camera = t_stage + offset); "
                        "default: estimated")  # fmt: skip
    p.add_argument("--contact-x-mm", type=float, action="append",
                   help="test 1: stage position at first contact, per trial; default: from "
                        "the pauses")  # fmt: skip
    p.add_argument("--forces", action="append", metavar="F.csv",
                   help="test 2: the trial's force log (docs/sensor.md section 7.1), per "
                        "trial; adds Fig. 6C's F_z RMSE: k_z times each pause's median dz "
                        "against the log's median")  # fmt: skip
    p.add_argument("--springs", metavar="FILE",
                   help="with --forces: the springs file giving k_z; default: the spring "
                        "model of Table I")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder for the per-pause CSV, the JSON summary and the figure")
    p.set_defaults(func=_run_validate)


def _run_validate(args) -> int:
    from camwhisker.calibration.validate import force_check, pooled, validate, write_validation
    from camwhisker.contact.stage import read_stage_log
    from camwhisker.io.forcelog import read_force_log
    from camwhisker.io.signals import read_signal_table
    from camwhisker.sensor.springs import suspension_stiffness

    pairs = paired_runs(args, "clock_offset_s", "contact_x_mm", "forces")
    sensor = load_sensor(args.sensor)
    if args.forces and args.test != 2:
        raise CommandError("--forces checks test 2 (F_z against dz)")
    springs = springs_of(args) or suspension_stiffness()
    results, forces = [], []
    for s, g, offset, x0, f in pairs:
        signals = read_signal_table(s)
        results.append(validate(signals, read_stage_log(g), args.test, offset, x0))
        if f is not None:
            forces.append(force_check(results[-1], signals, read_force_log(f), springs))
    paths = write_validation(results, args.out, sensor, command_line(args), forces)
    unit = results[0].spec.unit
    for k, r in enumerate(results, start=1):
        how = "estimated" if r.offset_estimated else "given"
        print(f"test {args.test}, trial {k}: offset {r.offset_s:+.3f} s ({how}); "
              f"{int(r.pauses['used'].sum())} pauses, {r.n_frames} frames; "
              f"RMSE {r.rmse:.4g} {unit}, bias {r.bias:+.4g} {unit}, slope {r.slope:.4f}")
    if len(results) > 1:
        s = pooled(results)
        print(f"test {args.test}, {len(results)} trials pooled: {s['frames_used']} frames; "
              f"RMSE {s[f'rmse_{unit}']:.4g} {unit}, bias {s[f'bias_{unit}']:+.4g} {unit}, "
              f"slope {s['slope']:.4f}")
    for k, f in enumerate(forces, start=1):
        how = "estimated" if f["force_offset_estimated"] else "given"
        print(f"test 2, trial {k}: F_z RMSE {f['fz_rmse_mN']:.3g} mN over {f['pauses']} pause "
              f"medians (k_z {f['k_z_n_per_mm'] * 1e3:.4g} mN/mm; force clock "
              f"{f['force_offset_s']:+.3f} s, {how})")
    for path in paths.values():
        print(f"wrote {path}")
    return 0
