"""calibrate-springs: k_z and k_phi from signal tables and force logs (docs/sensor.md 7.1, 7.2)."""

from __future__ import annotations

from camwhisker.cli.common import CommandError, command_line

__all__ = ["add_calibrate_springs"]


def add_calibrate_springs(sub) -> None:
    p = sub.add_parser("calibrate-springs",
                       help="fit the springs' k_z (and k_phi) against a force-torque log "
                            "(the paper's test 2), for --springs")
    p.add_argument("--signals", action="append", required=True, metavar="S.csv",
                   help="signal table of one run; repeat once per run")
    p.add_argument("--forces", action="append", required=True, metavar="F.csv",
                   help="force log of one run (t_s,fz_mN[,mb_Nmm]); repeat once per run, in "
                        "the order of --signals")
    p.add_argument("--clock-offset-s", type=float, action="append",
                   help="known clock offset per run (t_camera = t_force + offset); "
                        "default: estimated")  # fmt: skip
    p.add_argument("--springs", metavar="FILE",
                   help="springs file whose [design] gives the model values kept where "
                        "nothing is fitted; default: Table I")
    p.add_argument("--out", required=True, metavar="SPRINGS.toml", help="springs file to write")
    p.set_defaults(func=_run_calibrate_springs)


def _run_calibrate_springs(args) -> int:
    from camwhisker.calibration.springfile import read_design, write_springs
    from camwhisker.calibration.springs_fit import SpringRun, calibrate_springs
    from camwhisker.io.forcelog import read_force_log
    from camwhisker.io.signals import read_signal_table
    from camwhisker.sensor.springs import SpringDesign, suspension_stiffness

    n = len(args.signals)
    offsets = args.clock_offset_s or [None] * n
    if len(args.forces) != n or len(offsets) != n:
        raise CommandError(f"give one --forces (and --clock-offset-s, if any) per --signals "
                           f"({n} signals, {len(args.forces)} force logs, {len(offsets)} "
                           "offsets)")
    design = read_design(args.springs) if args.springs else SpringDesign()
    runs = [SpringRun(read_signal_table(s), read_force_log(f), o)
            for s, f, o in zip(args.signals, args.forces, offsets, strict=True)]
    calib = calibrate_springs(runs, suspension_stiffness(design))
    write_springs(args.out, calib, design, command_line(args))
    for k, (offset, estimated, score) in enumerate(calib.offsets, start=1):
        how = f"estimated, score {score:.3f}" if estimated else "given"
        print(f"run {k}: clock offset {offset:+.3f} s ({how})")
    for name, fit, model, unit, scale in (
            ("k_z", calib.k_z, calib.model.k_z_n_per_mm, "mN/mm", 1e3),
            ("k_phi", calib.k_phi, calib.model.k_phi_nmm_per_rad, "N mm/rad", 1.0)):
        if fit.fitted:
            lo, hi = fit.ci95
            print(f"{name} = {fit.value * scale:.5g} {unit} (95 % CI {lo * scale:.5g} - "
                  f"{hi * scale:.5g}; {fit.blocks} blocks); model {model * scale:.5g}")
        else:
            print(f"{name} = {model * scale:.5g} {unit} (model: {fit.why})")
    print(f"F_z per-frame RMSE {calib.rmse['fz_mN']:.3g} mN; M_b {calib.rmse['mb_Nmm']:.3g} N mm")
    print(f"wrote {args.out}")
    return 0
