"""Objects in 3-D from simulated sweeps lifted into space: identification, error, coverage.

The planar simulator's walls and cylinders (:mod:`camwhisker.sim.mechanics.objects`) are
exact 3-D objects when extruded across their plane: a wall is a plane, a cylinder one
whose axis is perpendicular to the plane of the sweep. Each run is swept at several
heights along that axis (:data:`HEIGHTS_MM`, each with its own noise), its stage motion
given as a pose log in a world frame turned and shifted from the simulator's
(:data:`WORLD_TURN_DEG`, :data:`WORLD_SHIFT_MM`), and the contacts placed by
:func:`camwhisker.contact.space.contact_rows_in_space`; :func:`~camwhisker.percept.solids.
perceive_solid` names the object. Spheres need the 3-D simulator: they are not here.
"""

from __future__ import annotations

import math
import time

import numpy as np
from scipy.spatial.transform import Rotation

from camwhisker.bench.contact import calibrate_simulated
from camwhisker.bench.percepts import PROTOCOL, _quiet
from camwhisker.contact.space import SpaceError, contact_rows_in_space
from camwhisker.io.poses import pose_log_from_arrays
from camwhisker.percept.solids import perceive_solid, surfels_from_tables
from camwhisker.sim.mechanics.experiment import FRONT_END_NOISE, NoiseModel, simulate_run
from camwhisker.sim.mechanics.objects import draw_sweep

__all__ = ["KINDS", "MODEL_OF", "HEIGHTS_MM", "CALIB_SEED", "TUNING_SEEDS", "HELD_OUT_SEEDS",
           "simulate_solid_sweep", "truth_in_world", "run_solid_sweep", "run_campaign",
           "summarise", "format_summary", "main"]  # fmt: skip

KINDS = ("wall", "cylinder", "none")
MODEL_OF = {"wall": "plane", "cylinder": "cylinder", "none": "none"}
#: Sweeps at these heights along the extrusion (mm): the axis is told by the spread.
HEIGHTS_MM = (-30.0, 0.0, 30.0)
#: The world frame: the simulator's turned by these Euler angles (zyx, deg) and shifted.
WORLD_TURN_DEG = (35.0, -20.0, 50.0)
WORLD_SHIFT_MM = (120.0, -40.0, 300.0)
CALIB_SEED = 500
TUNING_SEEDS = range(0, 30)
HELD_OUT_SEEDS = range(1000, 1060)

_WORLD = Rotation.from_euler("zyx", WORLD_TURN_DEG, degrees=True)


def _sim_frame(angle_deg: float) -> np.ndarray:
    """Columns x_S, y_S, z_S in the simulator's 3-D frame (plane x-z, extrusion y) of a run
    whose stage frame is turned by ``angle_deg``: x_S along the travel, z_S the shaft."""
    a = math.radians(angle_deg)
    x_s = np.array([math.cos(a), 0.0, math.sin(a)])
    z_s = np.array([-math.sin(a), 0.0, math.cos(a)])
    return np.column_stack([x_s, np.cross(z_s, x_s), z_s])


def _to_world(p_sim: np.ndarray) -> np.ndarray:
    return _WORLD.apply(p_sim) + np.asarray(WORLD_SHIFT_MM)


def _poses(run, pose: tuple, height_mm: float):
    """The run's stage motion as a pose log in the world frame."""
    x0, y0, angle = pose
    frame = _sim_frame(angle)
    x = np.asarray(run.stage["x_mm"], float)
    base = np.array([x0, height_mm, y0]) + np.outer(x, frame[:, 0])
    q = (_WORLD * Rotation.from_matrix(frame)).as_quat(scalar_first=True)
    return pose_log_from_arrays(run.stage["t_s"], _to_world(base), np.tile(q, (x.size, 1)),
                                f"<{run.name} poses>")  # fmt: skip


def simulate_solid_sweep(kind: str, rng, calib, noise: NoiseModel = FRONT_END_NOISE):
    """The object, and its runs at every height as contact tables with world columns."""
    sweep = draw_sweep(kind, rng)
    tables = []
    for h in HEIGHTS_MM:
        for i, spec in enumerate(sweep.runs):
            run = simulate_run(f"h{h:g}run{i}", "slide-box", spec.scene, rng, protocol=PROTOCOL,
                               noise=noise, travel_sign=spec.travel_sign)  # fmt: skip
            offset = None
            if kind == "none":
                run.signals = _quiet(run.signals, rng, noise)
                offset = run.offset_s
            try:
                cols, _, _ = contact_rows_in_space(run.signals, _poses(run, spec.pose, h), calib,
                                                   offset, mode="pause")  # fmt: skip
            except SpaceError:  # nothing touched: no direction, no contacts
                continue
            tables.append(cols)
    return sweep, tables


def truth_in_world(sweep) -> dict:
    """The true object in the world frame, with section 9's parameter names."""
    t = sweep.truth
    y_axis = _WORLD.apply([0.0, 1.0, 0.0])
    if sweep.kind == "cylinder":
        c = _to_world(np.array([t["center_x_mm"], 0.0, t["center_y_mm"]]))
        return {"center_mm": c, "axis": y_axis, "radius_mm": t["radius_mm"]}
    if sweep.kind == "wall":
        a = math.radians(t["angle_deg"])
        n_sim = np.array([-math.sin(a), 0.0, math.cos(a)])  # toward the side the base comes from
        point = _to_world(np.array([t["end_x_mm"], 0.0, t["end_y_mm"]]))
        n = _WORLD.apply(n_sim)
        return {"normal": n, "distance_mm": float(n @ point)}
    return {}


def _errors(kind: str, truth: dict, params: dict) -> dict:
    if kind == "cylinder":
        u = np.array([params["axis_x"], params["axis_y"], params["axis_z"]])
        c = np.array([params["center_x_mm"], params["center_y_mm"], params["center_z_mm"]])
        off = c - truth["center_mm"]
        off -= (off @ truth["axis"]) * truth["axis"]  # any point of the true axis will do
        return {"axis_err_deg": math.degrees(math.acos(min(1.0, abs(u @ truth["axis"])))),
                "radius_err_mm": abs(params["radius_mm"] - truth["radius_mm"]),
                "center_err_mm": float(np.linalg.norm(off))}
    if kind == "wall":
        n = np.array([params["normal_x"], params["normal_y"], params["normal_z"]])
        return {"normal_err_deg": math.degrees(math.acos(min(1.0, float(n @ truth["normal"])))),
                "distance_err_mm": abs(params["distance_mm"] - truth["distance_mm"])}
    return {}


def _true_params(kind: str, truth: dict, params: dict) -> dict:
    """The truth in the fitted parameters' names: a cylinder's centre as the point of the
    true axis nearest the fitted one, its axis with the fitted one's sign."""
    if kind == "wall":
        n = truth["normal"]
        return {"normal_x": n[0], "normal_y": n[1], "normal_z": n[2],
                "distance_mm": truth["distance_mm"]}
    u = truth["axis"]
    fitted_u = np.array([params["axis_x"], params["axis_y"], params["axis_z"]])
    u = u if u @ fitted_u >= 0 else -u
    c = np.array([params["center_x_mm"], params["center_y_mm"], params["center_z_mm"]])
    c = truth["center_mm"] + ((c - truth["center_mm"]) @ u) * u
    return {"center_x_mm": c[0], "center_y_mm": c[1], "center_z_mm": c[2], "axis_x": u[0],
            "axis_y": u[1], "axis_z": u[2], "radius_mm": truth["radius_mm"]}


def run_solid_sweep(seed: int, calib, noise: NoiseModel = FRONT_END_NOISE) -> dict:
    """One sweep: the object, the percept, its errors (where identified)."""
    rng = np.random.default_rng(seed)
    kind = KINDS[seed % len(KINDS)]
    t0 = time.perf_counter()
    sweep, tables = simulate_solid_sweep(kind, rng, calib, noise)
    s = surfels_from_tables(tables)
    p = perceive_solid(s)
    out = {"seed": seed, "kind": kind, "chosen": p.best.model, "runner_up": p.runner_up,
           "evidence_ratio": p.evidence_ratio, "n_surfels": s.n,
           "correct": p.best.model == MODEL_OF[kind], "s": time.perf_counter() - t0}
    right = p.fits.get(MODEL_OF[kind])
    if right is not None and kind != "none":
        truth = truth_in_world(sweep)
        out.update(_errors(kind, truth, right.params))
        true = _true_params(kind, truth, right.params)
        cover = [lo <= true[k] <= hi for k, (lo, hi) in right.intervals.items()]
        out["covered"], out["checked"] = int(sum(cover)), len(cover)
    return out


def run_campaign(seeds, calib_seed: int = CALIB_SEED, noise: NoiseModel = FRONT_END_NOISE,
                 progress=None) -> list[dict]:  # fmt: skip
    """Every sweep of ``seeds``, calibrated on simulated rigid pegs of ``calib_seed``."""
    calib = calibrate_simulated(calib_seed, noise=noise)
    rows = []
    for seed in seeds:
        rows.append(run_solid_sweep(seed, calib, noise))
        if progress:
            progress(rows[-1])
    return rows


def summarise(rows: list[dict]) -> dict:
    """Identification per kind and the medians of each error."""
    checked = sum(r.get("checked", 0) for r in rows)
    out = {"sweeps": len(rows), "identified": sum(r["correct"] for r in rows),
           "coverage": sum(r.get("covered", 0) for r in rows) / checked if checked else None}
    for kind in KINDS:
        mine = [r for r in rows if r["kind"] == kind]
        out[kind] = {"n": len(mine), "identified": sum(r["correct"] for r in mine)}
        for key in ("axis_err_deg", "radius_err_mm", "center_err_mm", "normal_err_deg",
                    "distance_err_mm"):
            vals = [r[key] for r in mine if key in r]
            if vals:
                out[kind][key] = {"median": float(np.median(vals)),
                                  "p95": float(np.percentile(vals, 95))}
    return out


def format_summary(s: dict) -> str:
    cover = f"{100 * s['coverage']:.1f} %" if s["coverage"] is not None else "n/a"
    lines = [f"identified {s['identified']} of {s['sweeps']} sweeps; 95 % intervals cover the "
             f"truth in {cover} of the parameters checked"]
    for kind in KINDS:
        k = s[kind]
        errs = ", ".join(f"{name} median {v['median']:.3g} (p95 {v['p95']:.3g})"
                         for name, v in k.items() if isinstance(v, dict))
        lines.append(f"  {kind:<9} {k['identified']} of {k['n']}" + (f"; {errs}" if errs else ""))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    import argparse

    from camwhisker.bench.seeds import seed_list
    from camwhisker.files.atomic import atomic_write_text
    from camwhisker.files.jsonfile import dumps

    p = argparse.ArgumentParser(prog="camwhisker dev solids-bench", description=__doc__)
    p.add_argument("--seeds", type=seed_list,
                   default=f"{HELD_OUT_SEEDS[0]}-{HELD_OUT_SEEDS[-1]}",
                   help=f"sweep seeds (seed %% 3: wall, cylinder, none); "
                        f"{TUNING_SEEDS[0]}-{TUNING_SEEDS[-1]} were used for tuning")
    p.add_argument("--out", metavar="R.json", help="also write the summary and every sweep")
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    rows = run_campaign(args.seeds)
    s = summarise(rows)
    print(format_summary(s))
    print(f"{len(rows)} sweeps in {time.perf_counter() - t0:.0f} s")
    if args.out:
        atomic_write_text(args.out, dumps({"summary": s, "sweeps": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
