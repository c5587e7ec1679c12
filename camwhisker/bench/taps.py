"""Seed 000's protocol redone with taps in 3-D: identification and localisation of spheres
and a plane, and the contact points themselves.

Seed 000 (Mitchinson et al. 2013): spheres of 200, 300 and 600 mm diameter and a plane,
ten locations 40 mm apart, an array of whiskers on a robot arm; identification 88-99 %,
spheres located within 29-46 mm (mean), the plane within 13-20 mm and 2-3 deg. Here a
trial (:func:`camwhisker.sim.mechanics.taps.protocol_trial`) is one stimulus at one
location tapped once by each of the rig's five sensors; each tap goes through
:func:`camwhisker.contact.space.contact_rows_in_space` (per pause, clock offsets
estimated) with the calibration of ``sample_frames/space/calib.toml`` (the simulator's
rigid pegs, the same whisker), and the trial's contacts through
:func:`camwhisker.percept.solids.perceive_solid` (plane, sphere, cylinder or none, no
prior on the radii, unlike seed 000's four known stimuli). Contact points are also scored
per frame (``--per frame``) against the simulator's true contact point, on frames with
phi >= 2 deg.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from camwhisker.contact.space import SpaceError, contact_rows_in_space
from camwhisker.io.poses import pose_log_from_arrays
from camwhisker.percept.solids import perceive_solid, surfels_from_tables
from camwhisker.sim.mechanics.experiment import FRONT_END_NOISE, NoiseModel
from camwhisker.sim.mechanics.taps import STIMULI, protocol_trial, simulate_trial

__all__ = ["CALIB_PATH", "TUNING_SEEDS", "HELD_OUT_SEEDS", "PAPER", "contact_errors",
           "object_errors", "run_trial", "summarise", "format_summary", "main"]  # fmt: skip

#: The contact calibration made from the simulator's stage runs (rigid pegs).
CALIB_PATH = Path(__file__).resolve().parents[2] / "sample_frames" / "space" / "calib.toml"
#: Seeds looked at while building the protocol and choosing the normals' scale (0-39).
TUNING_SEEDS = range(0, 40)
#: One trial per stimulus and location (seed % 4 stimulus, (seed // 4) % 10 location).
HELD_OUT_SEEDS = range(100, 140)
#: Frames scored for the contact point: phi at least this (deg).
SCORE_PHI_DEG = 2.0
#: Seed 000's results (strategies C1/C2/C3; means over test trials).
PAPER = {"identified_pct": "92/90/93 (L4-7: 99/97/85)",
         "sphere_center_mm": "37/38/46 mean (L4-7: 29/31/35)",
         "plane_distance_mm": "13/19/20 mean", "plane_normal_deg": "3/2/2 mean"}  # fmt: skip

_CENTER = ("center_x_mm", "center_y_mm", "center_z_mm")
_NORMAL = ("normal_x", "normal_y", "normal_z")
_POINT = ("px_mm", "py_mm", "pz_mm")


def _vec(d: dict, names) -> np.ndarray:
    return np.array([d[n] for n in names], float)


def contact_errors(cols: dict, tr) -> dict:
    """A tap's estimated contact points against the truth on frames with phi >= 2 deg:
    the 3-D distances and their parts along the shaft, along the press and across both."""
    p = np.column_stack([np.asarray(cols[c], float) for c in _POINT])
    phi = np.asarray(cols["phi_deg"], float)
    use = np.isfinite(p).all(axis=1) & np.isfinite(tr.contact).all(axis=1) & (phi >= SCORE_PHI_DEG)
    e = p[use] - tr.contact[use]
    side = np.cross(tr.tap.a, tr.tap.d)
    return {"dist": np.linalg.norm(e, axis=1), "shaft": e @ tr.tap.a, "press": e @ tr.tap.d,
            "side": e @ side}  # fmt: skip


def object_errors(kind: str, truth: dict, params: dict) -> dict:
    """A sphere's centre and radius errors, or a plane's normal (deg) and distance errors."""
    if kind == "sphere":
        off = _vec(params, _CENTER) - _vec(truth, _CENTER)
        return {"center_err_mm": float(np.linalg.norm(off)),
                "radius_err_mm": float(abs(params["radius_mm"] - truth["radius_mm"]))}
    cos = float(_vec(params, _NORMAL) @ _vec(truth, _NORMAL))
    return {"normal_err_deg": math.degrees(math.acos(min(1.0, cos))),
            "distance_err_mm": float(abs(params["distance_mm"] - truth["distance_mm"]))}


def _believed(tr, mount_error_deg: float, rng) -> tuple:
    """A tap's poses as a user who knows the sensor's mount to ``mount_error_deg`` gives
    them: turned by that angle about a random axis through the sensor."""
    t, p, q = tr.poses
    if not mount_error_deg:
        return t, p, q
    axis = rng.standard_normal(3)
    delta = Rotation.from_rotvec(math.radians(mount_error_deg) * axis / np.linalg.norm(axis))
    return t, p, (Rotation.from_quat(q, scalar_first=True) * delta.inv()).as_quat(
        scalar_first=True)


def _tables(runs, calib, mode: str, mount_error_deg: float = 0.0, seed: int = 0):
    tables, used = [], []
    rng = np.random.default_rng([seed, 11])
    for tr in runs:
        poses = pose_log_from_arrays(*_believed(tr, mount_error_deg, rng), f"<{tr.name}>")
        try:
            cols, run, _ = contact_rows_in_space(tr.signals, poses, calib, None, mode=mode)
        except SpaceError:  # no trusted contact row: this tap adds nothing
            continue
        tables.append(cols)
        used.append((tr, run.offset_s))
    return tables, used


def run_trial(seed: int, calib, noise: NoiseModel = FRONT_END_NOISE,
              mount_error_deg: float = 0.0) -> dict:  # fmt: skip
    """One trial: taps, contact tables (per pause for the percept, per frame for the points),
    the percept and its errors; the contact errors as arrays under ``"_contact"``. With
    ``mount_error_deg`` each sensor's pose is known only to that angle (:func:`_believed`)."""
    t0 = time.perf_counter()
    trial = protocol_trial(seed)
    runs = simulate_trial(trial, noise)
    tables, used = _tables(runs, calib, "pause", mount_error_deg, seed)
    s = surfels_from_tables(tables)
    p = perceive_solid(s)
    kind = trial.obj.kind
    truth = trial.obj.params()
    out = {"seed": seed, "stimulus": trial.stimulus, "location": trial.location + 1,
           "kind": kind, "radius_mm": STIMULI[trial.stimulus][1], "chosen": p.best.model,
           "runner_up": p.runner_up, "correct": p.best.model == kind, "n_surfels": s.n,
           "taps": len(runs), "taps_used": len(tables),
           "offset_err_s": [abs(o - tr.run.offset_s) for tr, o in used]}  # fmt: skip
    fit = p.fits.get(kind)
    if fit is not None:
        out.update(object_errors(kind, truth, fit.params))
        cover = [lo <= truth[k] <= hi for k, (lo, hi) in fit.intervals.items()]
        out["covered"], out["checked"] = int(sum(cover)), len(cover)
    frames, placed = _tables(runs, calib, "frame", mount_error_deg, seed)
    errs = [contact_errors(cols, tr) for cols, (tr, _) in zip(frames, placed, strict=True)]
    out["_contact"] = {k: np.concatenate([e[k] for e in errs]) if errs else np.empty(0)
                       for k in ("dist", "shaft", "press", "side")}  # fmt: skip
    out["s"] = time.perf_counter() - t0
    return out


def _stats(vals) -> dict:
    v = np.asarray(vals, float)
    if not v.size:
        return {"n": 0}
    return {"n": int(v.size), "median": float(np.median(v)), "mean": float(np.mean(v)),
            "p95": float(np.percentile(v, 95))}


def _group(rows: list[dict]) -> dict:
    out = {"trials": len(rows), "identified": int(sum(r["correct"] for r in rows))}
    for key in ("center_err_mm", "radius_err_mm", "normal_err_deg", "distance_err_mm"):
        vals = [r[key] for r in rows if key in r]
        if vals:
            out[key] = _stats(vals)
    return out


def summarise(rows: list[dict]) -> dict:
    """Identification (all, per stimulus, locations 4-7), the errors' medians, means and
    95th percentiles, the intervals' coverage and the contact points' errors."""
    checked = [r for r in rows if "checked" in r]
    n_checked = sum(r["checked"] for r in checked)
    out = {"all": _group(rows),
           "inner_L4_7": _group([r for r in rows if 4 <= r["location"] <= 7]),
           "coverage": sum(r["covered"] for r in checked) / n_checked if n_checked else None,
           "trials_all_covered": sum(r["covered"] == r["checked"] for r in checked),
           "trials_checked": len(checked),
           "stimuli": {}}  # fmt: skip
    for i, (kind, radius) in enumerate(STIMULI):
        name = f"sphere R{radius:g}" if kind == "sphere" else kind
        mine = [r for r in rows if r["stimulus"] == i]
        out["stimuli"][name] = _group(mine)
        if mine:
            out["stimuli"][name]["points_mm"] = _stats(np.concatenate([r["_contact"]["dist"]
                                                                       for r in mine]))
    c = {k: np.concatenate([r["_contact"][k] for r in rows]) for k in ("dist", "shaft",
                                                                        "press", "side")}
    out["contact_mm"] = {"dist": _stats(c["dist"]),
                         **{k: _stats(np.abs(c[k])) for k in ("shaft", "press", "side")},
                         "bias_shaft_mm": float(np.median(c["shaft"])) if c["shaft"].size else None,
                         "bias_press_mm": float(np.median(c["press"])) if c["press"].size else None}
    out["offset_err_s"] = _stats([e for r in rows for e in r["offset_err_s"]])
    return out


def _cell(g: dict, key: str) -> str:
    v = g.get(key)
    return f"{v['median']:.2g} / {v['p95']:.2g}" if v else "-"


def format_summary(s: dict) -> str:
    """The table beside seed 000's, then the contact points and the clock offsets."""
    a, inner = s["all"], s["inner_L4_7"]
    cover = f"{100 * s['coverage']:.0f} %" if s["coverage"] is not None else "n/a"
    lines = [f"identified {a['identified']} of {a['trials']} "
             f"({100 * a['identified'] / max(1, a['trials']):.0f} %; L4-7 "
             f"{inner['identified']} of {inner['trials']}); seed 000: {PAPER['identified_pct']}",
             f"95 % intervals cover the truth: {cover} of parameters, all of a trial's in "
             f"{s['trials_all_covered']} of {s['trials_checked']} trials",
             f"{'stimulus':<13}{'id':>7}  {'centre mm':>12}{'radius mm':>12}{'normal deg':>12}"
             f"{'dist mm':>12}{'points mm':>12}   (median / p95)"]  # fmt: skip
    for name, g in s["stimuli"].items():
        lines.append(f"{name:<13}{g['identified']:>3} of {g['trials']:<2} "
                     + "".join(f" {_cell(g, k):>11}" for k in ("center_err_mm", "radius_err_mm",
                                                               "normal_err_deg", "distance_err_mm",
                                                               "points_mm")))
    lines.append(f"seed 000: spheres located within {PAPER['sphere_center_mm']} mm; plane "
                 f"{PAPER['plane_distance_mm']} mm, {PAPER['plane_normal_deg']} deg")
    c = s["contact_mm"]
    if c["dist"]["n"]:
        lines.append(f"contact points (frames, phi >= {SCORE_PHI_DEG:g} deg, n {c['dist']['n']}): "
                     f"3-D error median {c['dist']['median']:.2f} mm, p95 {c['dist']['p95']:.2f}; "
                     f"|along shaft| {c['shaft']['median']:.2f} / {c['shaft']['p95']:.2f}, "
                     f"|along press| {c['press']['median']:.2f} / {c['press']['p95']:.2f}, "
                     f"|sideways| {c['side']['median']:.2g} / {c['side']['p95']:.2g} "
                     f"(median / p95); bias along shaft {c['bias_shaft_mm']:+.2f} mm")
    o = s["offset_err_s"]
    if o["n"]:
        lines.append(f"clock offsets from the pauses: error median {1e3 * o['median']:.0f} ms, "
                     f"p95 {1e3 * o['p95']:.0f} ms over {o['n']} taps")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    import argparse

    from tqdm import tqdm

    from camwhisker.bench.seeds import seed_list
    from camwhisker.contact.calibrate import read_calibration
    from camwhisker.files.atomic import atomic_write_text
    from camwhisker.files.jsonfile import dumps

    p = argparse.ArgumentParser(prog="camwhisker dev taps-bench", description=__doc__)
    p.add_argument("--seeds", type=seed_list,
                   default=f"{HELD_OUT_SEEDS[0]}-{HELD_OUT_SEEDS[-1]}",
                   help=f"trial seeds (seed %% 4: sphere R100, R150, R300, plane; (seed // 4) "
                        f"%% 10: location); {TUNING_SEEDS[0]}-{TUNING_SEEDS[-1]} were used "
                        f"for tuning (default: {HELD_OUT_SEEDS[0]}-{HELD_OUT_SEEDS[-1]})")
    p.add_argument("--calib", default=str(CALIB_PATH),
                   help="contact calibration (default: sample_frames/space/calib.toml)")
    p.add_argument("--mount-error-deg", type=float, default=0.0, metavar="DEG",
                   help="each sensor's mount known only to DEG, about a random axis: how well "
                        "a user must know the rig (default: 0, exact)")
    p.add_argument("--out", metavar="R.json", help="also write the summary and every trial")
    args = p.parse_args(argv)
    calib = read_calibration(args.calib)
    t0 = time.perf_counter()
    rows = [run_trial(seed, calib, mount_error_deg=args.mount_error_deg)
            for seed in tqdm(args.seeds, unit="trial", desc="taps")]
    s = summarise(rows)
    print(format_summary(s))
    print(f"{len(rows)} trials in {time.perf_counter() - t0:.0f} s")
    if args.out:
        trials = [{k: v for k, v in r.items() if k != "_contact"} for r in rows]
        atomic_write_text(args.out, dumps({"summary": s, "trials": trials}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
