"""The contact map: contact tables in W -> points (PLY), a voxel grid of belief (npz), a picture."""

from __future__ import annotations

import datetime as _dt
import math
from pathlib import Path

from camwhisker.cli.common import command_line

__all__ = ["add_map", "OUTPUT_SUFFIXES"]

#: What ``map --out MAP`` writes, in this order (the JSON summary last: its presence says
#: the others are complete).
OUTPUT_SUFFIXES = (".ply", ".npz", ".png", ".json")


def add_map(sub) -> None:
    from camwhisker.percept.contact_map import DEFAULT_ETA_DEG, SIGMA_MM, VOXEL_MM

    p = sub.add_parser(
        "map", help="a 3-D contact map from contact tables placed in the world (contact "
                    "--pose): the points as PLY, a voxel grid of contact belief, a picture",
        description="Writes MAP.ply (the contact points with their normal, belief, Z, r's "
        "spread, time and table), MAP.npz (a voxel grid of eq. 1's contact belief through a "
        "Gaussian, seed paper 000), MAP.png and MAP.json (a summary). docs/map.md.")
    p.add_argument("--contacts", action="append", required=True, metavar="C.csv",
                   help="a contact table with the world columns px_mm..nz (camwhisker contact "
                        "--pose); repeat for more tables")
    p.add_argument("--out", required=True, metavar="MAP",
                   help="the outputs' stem: MAP.ply, MAP.npz, MAP.png, MAP.json (a suffix of "
                        "one of them is dropped)")
    p.add_argument("--voxel-mm", type=float, default=VOXEL_MM, metavar="MM",
                   help="voxel side, mm (the paper's 10 mm cubes)")
    p.add_argument("--sigma-mm", type=float, default=SIGMA_MM, metavar="MM",
                   help="the Gaussian filter's standard deviation, mm (the paper's width)")
    p.add_argument("--memory-s", type=float, metavar="S",
                   help="only the points within S seconds of the last one enter the grid (the "
                        "paper's map has 1 s); default: all points")
    p.add_argument("--eta-deg", type=float, default=DEFAULT_ETA_DEG, metavar="X",
                   help="eta of eq. 1, b = clip(phi / eta - 1, 0, 1), deg (the contact "
                        "threshold plus 50 %%)")
    p.add_argument("--percept", metavar="P.json",
                   help="a percept file (camwhisker percept on world tables): its sphere, "
                        "cylinder or plane is drawn in MAP.png")
    p.set_defaults(func=_run_map)


def _check_options(args) -> Path:
    """The outputs' stem; raises ContactMapError (a ValueError) naming a bad option."""
    from camwhisker.percept.contact_map import ContactMapError

    for flag, value, least in (("--voxel-mm", args.voxel_mm, None),
                               ("--sigma-mm", args.sigma_mm, None),
                               ("--eta-deg", args.eta_deg, None),
                               ("--memory-s", args.memory_s, 0.0)):  # fmt: skip
        if value is None:
            continue
        bad = not math.isfinite(value) or (value < least if least is not None else value <= 0)
        if bad:
            need = f">= {least:g}" if least is not None else "> 0"
            raise ContactMapError(f"{flag} {value:g}: must be a finite number {need}")
    out = Path(args.out)
    return out.with_suffix("") if out.suffix in OUTPUT_SUFFIXES else out


def _summary(args, points, grid, shape, files: dict) -> dict:
    import numpy as np

    from camwhisker import __version__
    from camwhisker.files.digest import sha256_file

    per_table = np.bincount(points.table, minlength=len(points.sources))
    b = np.nan_to_num(points.belief, nan=0.0)
    return {
        "camwhisker": __version__,
        "command": command_line(args),
        "created_utc": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "inputs": [{"contacts": s, "sha256": sha256_file(s), "points": int(n)}
                   for s, n in zip(points.sources, per_table, strict=True)],
        "percept": None if shape is None else {"path": shape.source, "model": shape.model,
                                               "sha256": sha256_file(shape.source)},
        "options": {"voxel_mm": grid.voxel_mm, "sigma_mm": grid.sigma_mm,
                    "memory_s": grid.memory_s, "eta_deg": points.eta_deg},
        "points": {"n": points.n, "in_grid": grid.n_points, "belief_1": int((b >= 1).sum()),
                   "belief_0": int((b <= 0).sum()),
                   "z_at_least_1": int((np.abs(points.z_score) >= 1).sum()),
                   "t_first_s": float(np.nanmin(points.t_s)), "t_last_s": grid.t_last_s},
        "bounds_mm": {"points_min": points.p_mm.min(axis=0), "points_max": points.p_mm.max(axis=0),
                      "grid_origin": grid.origin_mm, "grid_upper": grid.upper_mm},
        "grid": {"shape": list(grid.belief.shape), "max_belief": float(grid.belief.max()),
                 "voxels_at_least_half": int((grid.belief >= 0.5).sum())},
        "files": files,
    }


def _run_map(args) -> int:
    from camwhisker.files.atomic import atomic_write_text
    from camwhisker.files.jsonfile import dumps
    from camwhisker.percept.contact_map import (
        belief_grid,
        plot_contact_map,
        read_contact_points,
        read_percept,
        write_grid_npz,
        write_ply,
    )

    stem = _check_options(args)
    # Everything read and computed before the first file is written: bad input writes nothing.
    shape = read_percept(args.percept) if args.percept else None
    points = read_contact_points(args.contacts, args.eta_deg)
    grid = belief_grid(points, args.voxel_mm, args.sigma_mm, args.memory_s)
    files = {s[1:]: str(stem.with_name(stem.name + s)) for s in OUTPUT_SUFFIXES}
    how = command_line(args)
    write_ply(files["ply"], points, comments=[how])
    write_grid_npz(files["npz"], grid, {"command": how, "eta_deg": points.eta_deg,
                                        "contacts": list(points.sources)})  # fmt: skip
    plot_contact_map(points, files["png"], how, shape)
    record = _summary(args, points, grid, shape, files)
    atomic_write_text(files["json"], dumps(record, indent=1) + "\n")
    s = record["points"]
    print(f"{points.n} contact points from {len(points.sources)} table(s), {s['belief_1']} "
          f"with b = 1 (eta {points.eta_deg:g} deg); grid "
          f"{' x '.join(map(str, grid.belief.shape))} of {grid.voxel_mm:g} mm voxels from "
          f"{grid.n_points} points, sigma {grid.sigma_mm:g} mm, peak belief "
          f"{record['grid']['max_belief']:.3f}")
    print("wrote " + ", ".join(files.values()))
    return 0
