"""Objects in 3-D from simulated sweeps lifted into space: identification, error, coverage.

The planar simulator's walls and cylinders, swept at several heights and given as pose
logs in a turned world frame (:mod:`camwhisker.sim.mechanics.space`), through
:func:`camwhisker.contact.space.contact_rows_in_space` (per pause) and
:func:`camwhisker.percept.solids.perceive_solid`. Spheres need the 3-D simulator: they
are not here.
"""

from __future__ import annotations

import math
import time

import numpy as np

from camwhisker.bench.contact import calibrate_simulated
from camwhisker.bench.percepts import _quiet
from camwhisker.contact.space import SpaceError, contact_rows_in_space
from camwhisker.io.poses import pose_log_from_arrays
from camwhisker.percept.percepts import BLIND_TURN_DEG
from camwhisker.percept.solids import (
    MIN_SURFELS,
    fit_solid,
    next_plane_run,
    perceive_solid,
    surfels_from_tables,
)
from camwhisker.sim.mechanics.experiment import FRONT_END_NOISE, NoiseModel
from camwhisker.sim.mechanics.space import simulate_space_sweep, truth_in_world, turned_wall_runs

__all__ = ["KINDS", "MODEL_OF", "CALIB_SEED", "TUNING_SEEDS", "HELD_OUT_SEEDS",
           "contact_tables", "object_errors", "run_solid_sweep", "run_campaign", "summarise",
           "format_summary", "main"]  # fmt: skip

KINDS = ("wall", "cylinder", "none")
MODEL_OF = {"wall": "plane", "cylinder": "cylinder", "none": "none"}
CALIB_SEED = 500
TUNING_SEEDS = range(0, 30)
HELD_OUT_SEEDS = range(1000, 1060)


def contact_tables(kind: str, rng, calib, noise: NoiseModel = FRONT_END_NOISE):
    """The object and its runs at every height as contact tables with world columns; a
    wall (and the nothing in its place) gets a second run at every height, turned as the
    first run's plane asks (:func:`~camwhisker.percept.solids.next_plane_run`)."""
    sweep, runs = simulate_space_sweep(kind, rng, noise, quiet=_quiet)
    tables = _tables(kind, runs, calib)
    if kind in ("wall", "none"):
        s = surfels_from_tables(tables)
        plane = fit_solid("plane", s) if s.n >= MIN_SURFELS else None
        turn = next_plane_run(plane, s) if plane is not None else None
        more = turned_wall_runs(sweep, turn["turn_deg"] if turn else BLIND_TURN_DEG, rng, noise)
        if kind == "none":
            for lr in more:
                lr.run.signals = _quiet(lr.run.signals, rng, noise)
        tables += _tables(kind, more, calib)
    return sweep, tables


def _tables(kind: str, runs, calib) -> list[dict]:
    tables = []
    for lr in runs:
        # Nothing touched: nothing to align the clocks on, the user gives the offset.
        offset = lr.run.offset_s if kind == "none" else None
        try:
            cols, _, _ = contact_rows_in_space(lr.run.signals,
                                               pose_log_from_arrays(*lr.poses, f"<{lr.name}>"),
                                               calib, offset, mode="pause")  # fmt: skip
        except SpaceError:  # nothing touched: no direction, no contacts
            continue
        tables.append(cols)
    return tables


def _vec(d: dict, names) -> np.ndarray:
    return np.array([d[n] for n in names], float)


_CENTER = ("center_x_mm", "center_y_mm", "center_z_mm")
_AXIS = ("axis_x", "axis_y", "axis_z")
_NORMAL = ("normal_x", "normal_y", "normal_z")


def object_errors(kind: str, truth: dict, params: dict) -> dict:
    """The fit's errors against the true object (section 9's names): axis, radius and centre
    of a cylinder; normal and distance of a plane."""
    if kind == "cylinder":
        u, true_u = _vec(params, _AXIS), _vec(truth, _AXIS)
        off = _vec(params, _CENTER) - _vec(truth, _CENTER)
        off -= (off @ true_u) * true_u  # any point of the true axis will do
        return {"axis_err_deg": math.degrees(math.acos(min(1.0, abs(u @ true_u)))),
                "radius_err_mm": abs(params["radius_mm"] - truth["radius_mm"]),
                "center_err_mm": float(np.linalg.norm(off))}
    if kind == "wall":
        cos = float(_vec(params, _NORMAL) @ _vec(truth, _NORMAL))
        return {"normal_err_deg": math.degrees(math.acos(min(1.0, cos))),
                "distance_err_mm": abs(params["distance_mm"] - truth["distance_mm"])}
    return {}


def _true_params(kind: str, truth: dict, params: dict) -> dict:
    """The truth as the fit reports it: a cylinder's centre as the point of the true axis
    nearest the fitted one, its axis with the fitted one's sign."""
    if kind == "wall":
        return truth
    u = _vec(truth, _AXIS)
    u = u if u @ _vec(params, _AXIS) >= 0 else -u
    c0 = _vec(truth, _CENTER)
    c = c0 + ((_vec(params, _CENTER) - c0) @ u) * u
    return {**dict(zip(_CENTER, c, strict=True)), **dict(zip(_AXIS, u, strict=True)),
            "radius_mm": truth["radius_mm"]}


def run_solid_sweep(seed: int, calib, noise: NoiseModel = FRONT_END_NOISE) -> dict:
    """One sweep: the object, the percept, its errors (where identified)."""
    rng = np.random.default_rng(seed)
    kind = KINDS[seed % len(KINDS)]
    t0 = time.perf_counter()
    sweep, tables = contact_tables(kind, rng, calib, noise)
    s = surfels_from_tables(tables)
    p = perceive_solid(s)
    out = {"seed": seed, "kind": kind, "chosen": p.best.model, "runner_up": p.runner_up,
           "evidence_ratio": p.evidence_ratio, "n_surfels": s.n,
           "correct": p.best.model == MODEL_OF[kind], "s": time.perf_counter() - t0}
    right = p.fits.get(MODEL_OF[kind])
    if right is not None and kind != "none":
        truth = truth_in_world(sweep)
        out.update(object_errors(kind, truth, right.params))
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
