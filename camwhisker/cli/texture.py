"""Texture from sliding: simulate-texture (a run to files), texture (gap and amplitude)."""

from __future__ import annotations

import sys

from camwhisker.cli.common import CommandError, command_line, sensor_arg

__all__ = ["add_simulate_texture", "add_texture"]


def _positive(args, *names) -> None:
    for name in names:
        value = getattr(args, name)
        if not value > 0:
            raise CommandError(f"--{name.replace('_', '-')}: must be positive, got {value:g}")


def add_simulate_texture(sub) -> None:
    from camwhisker.sim.mechanics.experiment import (
        FRONT_END_NOISE_DZ_MM,
        FRONT_END_NOISE_PHI_DEG,
    )

    p = sub.add_parser("simulate-texture",
                       help="simulate the whisker's tip sliding over ridges, filmed (signals, "
                            "stage log, truth); the defaults make sample_frames/texture")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder for signals.csv, stage.csv, truth.csv and texture.json")
    p.add_argument("--gap-mm", type=float, default=1.0, help="the ridges' spacing")
    p.add_argument("--amplitude-mm", type=float, default=0.1,
                   help="the ridges' height, peak to valley")
    p.add_argument("--speed-mm-s", type=float, default=1.0, metavar="V",
                   help="the base's sliding speed")
    p.add_argument("--fps", type=float, default=120.0, help="the camera's frame rate")
    p.add_argument("--seed", type=int, default=0, help="seed of the noise and the clock offset")
    p.add_argument("--noise-phi-deg", type=float, default=FRONT_END_NOISE_PHI_DEG,
                   help="per-frame phi noise (default: our front end's)")
    p.add_argument("--noise-dz-mm", type=float, default=FRONT_END_NOISE_DZ_MM,
                   help="per-frame dz noise (default: our front end's)")
    sensor_arg(p, "sensor file, for the whisker's length; default: Table I values")
    p.set_defaults(func=_run_simulate_texture)


def _run_simulate_texture(args) -> int:
    from camwhisker.sensor.file import load_sensor
    from camwhisker.sim.mechanics import NoiseModel, WhiskerMechanics
    from camwhisker.sim.mechanics.files import write_texture_run
    from camwhisker.sim.mechanics.texture import (
        TextureProtocol,
        TextureSurface,
        simulate_texture,
    )

    _positive(args, "gap_mm", "speed_mm_s", "fps")
    if not args.amplitude_mm >= 0:
        raise CommandError(f"--amplitude-mm: must be >= 0, got {args.amplitude_mm:g}")
    if args.noise_phi_deg < 0 or args.noise_dz_mm < 0:
        raise CommandError("--noise-phi-deg and --noise-dz-mm must be >= 0")
    mech = WhiskerMechanics(length_mm=load_sensor(args.sensor).whisker.length_mm)
    noise = NoiseModel(phi_deg=args.noise_phi_deg, dz_mm=args.noise_dz_mm)
    protocol = TextureProtocol(speed_mm_s=args.speed_mm_s, fps=args.fps, noise=noise)
    run = simulate_texture(TextureSurface(args.gap_mm, args.amplitude_mm), protocol, args.seed,
                           mech)
    paths = write_texture_run(run, args.out, command_line(args))
    i = run.info
    print(f"texture at {i['texture_frequency_hz']:.3g} Hz (gap {args.gap_mm:g} mm at "
          f"{args.speed_mm_s:g} mm/s), whisker's mode {i['natural_hz']:.3f} Hz, "
          f"{run.signals['t_s'].size} frames at {args.fps:g} frames/s")
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0


def add_texture(sub) -> None:
    p = sub.add_parser("texture", help="gap and amplitude of a texture slid over, with their "
                                       "uncertainty, or the limit where it cannot be resolved")
    p.add_argument("--signals", required=True, metavar="S.csv",
                   help="signal table: at rest first, then sliding, then let go (free ringing)")
    p.add_argument("--speed-mm-s", required=True, type=float, metavar="V",
                   help="the base's sliding speed")
    p.add_argument("--stage", metavar="LOG",
                   help="stage log (t_s, x_mm): the speed measured from its moving samples "
                        "is used, with its standard error, instead of V")
    sensor_arg(p, "sensor file, for the whisker's length; default: Table I values")
    p.add_argument("--out", required=True, metavar="T.json", help="the estimate to write")
    p.add_argument("--plot", metavar="T.png",
                   help="also draw the tip's push, the filtered signal, its extrema and the "
                        "free ringing")
    p.set_defaults(func=_run_texture)


def _speed(args):
    """(speed, its standard error) from the stage log where given, else V (exact)."""
    if args.stage is None:
        return args.speed_mm_s, 0.0
    from camwhisker.contact.stage import read_stage_log
    from camwhisker.percept.texture import stage_speed

    log = read_stage_log(args.stage)
    speed, se = stage_speed(log.t_s, log.x_mm, args.stage)
    if abs(speed / args.speed_mm_s - 1.0) > 0.05:
        print(f"camwhisker texture: warning: {args.stage}: the stage moves at {speed:.4g} mm/s, "
              f"not {args.speed_mm_s:g}; using the log's", file=sys.stderr)
    return speed, se


def _run_texture(args) -> int:
    from camwhisker import __version__
    from camwhisker.files.atomic import atomic_write_text
    from camwhisker.files.jsonfile import dumps
    from camwhisker.io.signals import read_signal_table
    from camwhisker.percept.texture import estimate_texture, texture_record
    from camwhisker.sensor.file import load_sensor

    _positive(args, "speed_mm_s")
    length = load_sensor(args.sensor).whisker.length_mm
    speed, speed_se = _speed(args)
    est = estimate_texture(read_signal_table(args.signals), speed, length, speed_se)
    record = {"camwhisker": __version__, "command": command_line(args), **texture_record(est)}
    if args.plot:
        from camwhisker.contact.plots import plot_texture

        plot_texture(est, args.plot, command_line(args))
    atomic_write_text(args.out, dumps(record, indent=1) + "\n")
    lim = est.limits
    if est.resolved:
        print(f"gap {est.gap_mm:.4g} +- {est.gap_se_mm:.2g} mm, amplitude {est.amplitude_mm:.4g} "
              f"+- {est.amplitude_se_mm:.2g} mm (texture at {est.details['texture_hz']:.3g} Hz)")
    else:
        print(f"not resolved: {est.reason}")
    print(f"limits at {speed:.4g} mm/s: gap >= {lim['gap_min_mm']:.3g} mm ({lim['binding']}: "
          f"whisker's mode {est.ringing.natural_hz:.3f} Hz, corner {lim['cutoff_hz']:.3g} Hz; "
          f"Nyquist {lim['nyquist_gap_min_mm']:.3g} mm), amplitude >= "
          f"{lim['amplitude_min_mm']:.3g} mm")
    print(f"wrote {args.out}" + (f" and {args.plot}" if args.plot else ""))
    return 0
