"""validate: the paper's accuracy tests (Fig. 6 A/B) from a signal table and a stage log."""

from __future__ import annotations

from camwhisker.cli.common import command_line, sensor_arg
from camwhisker.sensor import load_sensor

__all__ = ["add_validate"]


def add_validate(sub) -> None:
    p = sub.add_parser("validate", help="applied against measured phi (test 1) or dz (test 2), "
                                        "RMSE and the plot of Fig. 6 A/B")
    p.add_argument("--signals", required=True, metavar="S.csv", help="signal table of one trial")
    p.add_argument("--stage", required=True, metavar="L.csv",
                   help="its stage log: with r_mm (test 1) or dz_mm (test 2)")
    p.add_argument("--test", required=True, type=int, choices=(1, 2),
                   help="1: rigid whisker stepped at a known r (phi); 2: known dz steps")
    sensor_arg(p, "sensor file the signals were made with (recorded in the summary)")
    p.add_argument("--clock-offset-s", type=float,
                   help="known clock offset (t_camera = t_stage + offset); default: estimated")
    p.add_argument("--contact-x-mm", type=float,
                   help="test 1: stage position at first contact; default: from the pauses")
    p.add_argument("--out", required=True, metavar="DIR")
    p.set_defaults(func=_run_validate)


def _run_validate(args) -> int:
    from camwhisker.signals import read_signal_table
    from camwhisker.stage import read_stage_log
    from camwhisker.validate import validate, write_validation

    sensor = load_sensor(args.sensor)
    result = validate(read_signal_table(args.signals), read_stage_log(args.stage), args.test,
                      args.clock_offset_s, args.contact_x_mm)
    paths = write_validation(result, args.out, sensor, command_line(args))
    unit = result.spec.unit
    how = "estimated" if result.offset_estimated else "given"
    print(f"test {args.test}: offset {result.offset_s:+.3f} s ({how}); "
          f"{int(result.pauses['used'].sum())} pauses, {result.n_frames} frames; "
          f"RMSE {result.rmse:.4g} {unit}, bias {result.bias:+.4g} {unit}, "
          f"slope {result.slope:.4f}")
    for path in paths.values():
        print(f"wrote {path}")
    return 0
