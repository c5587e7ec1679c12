"""Shape percepts: percept (contact tables -> wall, cylinder, corner or nothing), percept-bench."""

from __future__ import annotations

import datetime as _dt
import math

from camwhisker.cli.common import CommandError, command_line

__all__ = ["add_percept", "add_percept_bench"]


def add_percept(sub) -> None:
    p = sub.add_parser("percept", help="the object behind contact tables: wall, cylinder, box "
                                       "corner or nothing, with 95 %% intervals")
    p.add_argument("--contacts", action="append", required=True, metavar="C.csv",
                   help="a contact table (camwhisker contact); repeat for more sweeps. Tables "
                        "with the contact point in space (contact --pose: px_mm ...) give a "
                        "plane, sphere, cylinder or nothing in that frame (docs/sensor.md "
                        "section 9)")
    p.add_argument("--pose", action="append", metavar="X0,Y0,DEG",
                   help="where a table's stage frame lies in the common frame (common = "
                        "(X0, Y0) + rotation by DEG of the stage's x, y); once per --contacts "
                        "or not at all (default: 0,0,0, all in one frame)")
    p.add_argument("--out", required=True, metavar="P.json", help="the percept to write")
    p.add_argument("--plot", metavar="P.png", help="also draw the contacts and fitted outline")
    p.set_defaults(func=_run_percept)


def _poses(args):
    from camwhisker.percept.surfels import Pose

    if not args.pose:
        return [Pose()] * len(args.contacts)
    if len(args.pose) != len(args.contacts):
        raise CommandError(f"give --pose for every --contacts or for none ({len(args.contacts)} "
                           f"tables, {len(args.pose)} poses)")
    poses = []
    for text in args.pose:
        try:
            x0, y0, deg = (float(v) for v in text.split(","))
        except ValueError:
            raise CommandError(f"--pose {text!r}: expected X0,Y0,DEG (three numbers)") from None
        poses.append(Pose(x0, y0, deg))
    return poses


def _in_space(paths) -> bool:
    """Whether the tables hold contact points in W: all of them, or (an error) only some."""
    from camwhisker.files.tables import read_header

    has = [("px_mm" in read_header(p)) for p in paths]
    if any(has) and not all(has):
        raise CommandError("--contacts: give tables all from contact --pose (points in space) "
                           "or all from a stage (points in its plane), not both")
    return all(has)


def _run_percept_in_space(args) -> int:
    from camwhisker import __version__
    from camwhisker.files.atomic import atomic_write_text
    from camwhisker.files.digest import sha256_file
    from camwhisker.files.jsonfile import dumps
    from camwhisker.percept.percepts import RISE_DEG
    from camwhisker.percept.solids import perceive_solid, read_surfels3, solid_record

    if args.pose or args.plot:
        raise CommandError("--pose and --plot are for stage tables; tables in space carry their "
                           "own frame (draw them with camwhisker map --percept)")
    surfels = read_surfels3(args.contacts)
    p = perceive_solid(surfels)
    record = {"camwhisker": __version__, "command": command_line(args),
              "created_utc": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
              "inputs": [{"contacts": str(c), "sha256": sha256_file(c)} for c in args.contacts],
              **solid_record(p, surfels)}  # fmt: skip
    atomic_write_text(args.out, dumps(record, indent=1) + "\n")
    params = ", ".join(f"{k} {v:.3g} [{lo:.3g}, {hi:.3g}]"
                       for (k, v), (lo, hi) in zip(p.best.params.items(),
                                                   p.best.intervals.values(), strict=True))
    print(f"{p.best.model} from {surfels.n} contacts" + (f": {params}" if params else "")
          + (f"; runner-up {p.runner_up}, evidence ratio {p.evidence_ratio:.3g}"
             if p.runner_up else ""))  # fmt: skip
    if record["next_run"] is not None:
        r = record["next_run"]
        print(f"for a run over which the plane rises at {RISE_DEG:g} deg: turn the first run's "
              f"travel and shaft by {r['turn_deg']:.1f} deg about ({r['about_x']:.3f}, "
              f"{r['about_y']:.3f}, {r['about_z']:.3f})")
    if record["next_touch"] is not None:
        t = record["next_touch"]
        point = ", ".join(f"{t[f'point_{k}_mm']:.1f}" for k in "xyz")
        normal = ", ".join(f"{t[f'normal_{k}']:.3f}" for k in "xyz")
        print(f"next touch, to shrink the {p.best.model}'s confidence region to "
              f"{t['shrink']:.2f} of its volume: the point ({point}) mm, moving along "
              f"-({normal})")
    print(f"wrote {args.out}")
    return 0


def _run_percept(args) -> int:
    if _in_space(args.contacts):
        return _run_percept_in_space(args)
    from camwhisker import __version__
    from camwhisker.files.atomic import atomic_write_text
    from camwhisker.files.digest import sha256_file
    from camwhisker.files.jsonfile import dumps
    from camwhisker.percept.percepts import (
        RISE_DEG,
        object_of,
        outline,
        perceive,
        percept_record,
    )
    from camwhisker.percept.surfels import read_surfels

    poses = _poses(args)
    surfels = read_surfels(args.contacts, poses)
    p = perceive(surfels)
    record = {
        "camwhisker": __version__,
        "command": command_line(args),
        "created_utc": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "inputs": [{"contacts": str(c), "sha256": sha256_file(c), "pose": vars(pose)}
                   for c, pose in zip(args.contacts, poses, strict=True)],
        **percept_record(p),
    }
    if args.plot:
        from camwhisker.contact.plots import plot_percept

        label = f"percept: {object_of(p)}"
        plot_percept(surfels.xy_mm, surfels.dir, surfels.free_xy_mm,
                     outline(p.best, surfels.xy_mm), label, args.plot, command_line(args))
    atomic_write_text(args.out, dumps(record, indent=1) + "\n")
    params = ", ".join(f"{k} {v:.2f} [{lo:.2f}, {hi:.2f}]"
                       for (k, v), (lo, hi) in zip(p.best.params.items(),
                                                   p.best.intervals.values(), strict=True))
    print(f"{object_of(p)} ({p.best.model}) from {surfels.n} contacts"
          + (f": {params}" if params else "")
          + (f"; runner-up {p.runner_up}, evidence ratio {p.evidence_ratio:.3g}"
             if p.runner_up else ""))
    if p.best.model == "line":
        print(f"for a run over which it rises at {RISE_DEG:g} deg (MF places a contact best "
              f"when it slides at a steep phi): --pose X0,Y0,{record['next_run_angle_deg']:.1f}")
    print(f"wrote {args.out}" + (f" and {args.plot}" if args.plot else ""))
    return 0


def add_percept_bench(sub) -> None:
    p = sub.add_parser("percept-bench", help="shape percepts on simulated sweeps: identification, "
                                             "localisation error, interval coverage, the walls' "
                                             "bound from the pauses' noise")
    p.add_argument("--seeds", default="1000-1199", metavar="A-B",
                   help="sweep seeds, inclusive (0-399 and 2000-2999 were used to choose the "
                        "constants; 1000-1599, 3000-3599 and 4000-4599 are held out)")
    p.add_argument("--calib-pegs", type=int, default=8, metavar="N",
                   help="rigid pegs the simulated calibration is made on: 8, the paper's radii "
                        "(default), or N spaced evenly in log r over 22.5-90 mm")
    p.add_argument("--noise", default="0.05,0.02", metavar="PHI_DEG,DZ_MM",
                   help="the front end's noise per frame, phi (deg) and dz (mm), of the "
                        "calibration and the sweeps (default: its targets)")
    p.add_argument("--out", metavar="R.json", help="also write every sweep's result here")
    p.add_argument("--plot", metavar="W.png",
                   help="also draw each wall's angle error against its bound's sd")
    p.set_defaults(func=_run_percept_bench)


def _run_percept_bench(args) -> int:
    from camwhisker.bench.percepts import format_summary, run_campaign, summarise
    from camwhisker.bench.seeds import seed_list
    from camwhisker.files.atomic import atomic_write_text
    from camwhisker.files.jsonfile import dumps
    from camwhisker.sim.mechanics.experiment import NoiseModel, peg_radii

    try:
        seeds = seed_list(args.seeds)
    except ValueError as exc:
        raise CommandError(f"--{exc}") from None
    try:
        peg_radii(args.calib_pegs)
    except ValueError as exc:
        raise CommandError(f"--calib-pegs {args.calib_pegs}: {exc}") from None
    try:
        phi, dz = (float(v) for v in args.noise.split(","))
    except ValueError:
        raise CommandError(f"--noise {args.noise!r}: expected PHI_DEG,DZ_MM (two numbers)"
                           ) from None
    if not (0 < phi < math.inf and 0 < dz < math.inf):
        raise CommandError(f"--noise {args.noise!r}: both must be positive and finite")
    rows = run_campaign(seeds, pegs=args.calib_pegs,
                        noise=NoiseModel(phi_deg=phi, dz_mm=dz))
    s = summarise(rows)
    print(format_summary(s))
    if args.out:
        atomic_write_text(args.out, dumps({"command": command_line(args), "summary": s,
                                           "sweeps": rows}, indent=1) + "\n")
        print(f"wrote {args.out}")
    if args.plot:
        from camwhisker.bench.percepts import plot_wall_bounds

        plot_wall_bounds(rows, args.plot, command_line(args))
        print(f"wrote {args.plot}")
    return 0
