"""A sweep in space filmed and tracked: contact points and the object against the truth.

Renders a wall or cylinder swept at three heights in space, with its calibration
(:func:`camwhisker.sim.render.space.render_space_experiment`; kept with ``--cache``),
runs ``camwhisker experiment`` on the folder as a user would, and scores every contact
point on frames with phi >= 2 deg against the true point of contact (the distance in W:
along the shaft too, which a surface distance would hide), and the object's parameters.
With ``--rig`` the heights are three sensors on one carrier (a rig file, a folder per
sensor, the carrier's pose log per run: :mod:`camwhisker.run.rig_experiment`).
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from camwhisker.bench.solids import object_errors
from camwhisker.files.tables import read_columns
from camwhisker.run.experiment import run_experiment
from camwhisker.sim.render.space import render_space_experiment

__all__ = ["MIN_PHI_DEG", "point_errors", "main"]

#: Frames scored: the issue's phi >= 2 deg (below, GM's dx and phi are both near zero).
MIN_PHI_DEG = 2.0
_P = ("px_mm", "py_mm", "pz_mm")
_KIND_OF = {"plane": "wall", "cylinder": "cylinder"}


def point_errors(folder: Path, out: Path, runs: list[str]) -> dict:
    """Distances (mm) of each run's contact points from the true ones, phi >= 2 deg; a rig's
    runs named ``SENSOR/RUN``."""
    errors, slipping = [], []
    for name in runs:
        sensor, _, run = name.rpartition("/")
        table = out / sensor / "contact" / f"{run}.csv"  # a one-sensor run: out/contact/RUN.csv
        got = read_columns(table, ("t_s", "phi_deg", *_P))
        truth = read_columns(folder / f"{name}.contact_truth.csv", ("t_s", "slipping", *_P))
        n = min(got["t_s"].size, truth["t_s"].size)
        e = np.linalg.norm(np.column_stack([got[k][:n] - truth[k][:n] for k in _P]), axis=1)
        keep = (got["phi_deg"][:n] >= MIN_PHI_DEG) & np.isfinite(e)
        errors.append(e[keep])
        slipping.append(truth["slipping"][:n][keep] == 1)
    e, s = np.concatenate(errors), np.concatenate(slipping)

    def stats(v):
        return {"n": int(v.size), "median_mm": float(np.median(v)) if v.size else math.nan,
                "p95_mm": float(np.percentile(v, 95)) if v.size else math.nan}

    return {"all": stats(e), "stuck": stats(e[~s]), "slipping": stats(e[s])}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="camwhisker dev space-filmed-bench", description=__doc__)
    p.add_argument("--kind", choices=("wall", "cylinder"), default="cylinder",
                   help="the object swept")
    p.add_argument("--seed", type=int, default=1, help="seed of the object and the renders")
    p.add_argument("--cache", type=Path, help="keep the rendered folder here (reused)")
    p.add_argument("--rig", action="store_true",
                   help="the heights as three sensors on one carrier, each with its own "
                        "videos and calibration")  # fmt: skip
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.cache or Path(tmp) / "films"
        if not (folder / "object.json").is_file():
            render_space_experiment(folder, args.kind, args.seed, rig=args.rig)
        made = json.loads((folder / "object.json").read_text())
        s = run_experiment(folder, Path(tmp) / "out", progress=False)
        names = [f"{r['sensor']}/{r['name']}" if "sensor" in r else r["name"]
                 for r in made["runs"]]  # fmt: skip
        points = point_errors(folder, Path(tmp) / "out", names)
    truth, space = made["object"], s["space"]
    print(f"{args.kind} seed {args.seed}{' (rig)' if args.rig else ''}: percept "
          f"{space['model']} (truth {truth['model']}), {space['contacts']} contacts")
    if space["model"] == truth["model"]:
        errs = object_errors(_KIND_OF[truth["model"]], truth, space["params"])
        print("  " + ", ".join(f"{k} {v:.3g}" for k, v in errs.items()))
    for part, v in points.items():
        print(f"  contact points, phi >= {MIN_PHI_DEG:g} deg, {part}: {v['n']} frames, median "
              f"{v['median_mm']:.2f} mm, p95 {v['p95_mm']:.2f} mm")
    print(f"{time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
