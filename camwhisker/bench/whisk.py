"""Contact placed in space for a base that turns: simulated whisks, with and without the
turning base's model.

``camwhisker dev whisk-bench [--kind wall|cylinder] [--seeds 10-19] [--per frame|pause]``:
each seed's whisk (:mod:`camwhisker.sim.mechanics.whisk`: the base turns about a pivot
behind it while the contact sticks to a wall or rolls on a cylinder) through
:func:`~camwhisker.contact.space.contact_rows_in_space`, the clock offset estimated; the
3-D distance of each contact point from the true one on frames with phi >= 2 deg. "Without"
is the one-axis travel: the base's own position along theta, its direction fixed at the
first pose, as if it did not turn. Calibration: sample_frames/space/calib.toml. Seeds 0-9
tuned the turning model's solve for r; 10-19 are held out.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from camwhisker.bench.seeds import seed_list
from camwhisker.bench.taps import CALIB_PATH
from camwhisker.contact.calibrate import read_calibration
from camwhisker.contact.pipeline import contact_rows
from camwhisker.contact.space import WORLD_COLUMNS, contact_rows_in_space, placed_in_world
from camwhisker.contact.stage import stage_log_from_arrays
from camwhisker.io.poses import MAX_GAP_S, pose_log_from_arrays
from camwhisker.sim.mechanics.whisk import draw_whisk_object, simulate_whisk

__all__ = ["MIN_PHI_DEG", "point_errors", "run_whisk", "main"]

#: Frames scored: in contact with phi at least this (deg), as the other 3-D benchmarks.
MIN_PHI_DEG = 2.0


def point_errors(cols: dict, truth: np.ndarray) -> np.ndarray:
    """3-D distances (mm) of the table's contact points from the true ones, phi >= 2 deg."""
    p = np.column_stack([np.asarray(cols[c], float) for c in WORLD_COLUMNS[:3]])
    e = np.linalg.norm(p - truth[: p.shape[0]], axis=1)
    return e[(np.asarray(cols["phi_deg"], float) >= MIN_PHI_DEG) & np.isfinite(e)]


def run_whisk(kind: str, seed: int, calib, per: str) -> dict:
    """One whisk: errors with the turning model and with the one-axis travel, offset error."""
    rng = np.random.default_rng(seed)
    run = simulate_whisk(f"{kind}{seed}", draw_whisk_object(kind, rng), rng)
    t, p, q = run.poses
    poses = pose_log_from_arrays(t, p, q, f"{run.name}.pose.csv")
    truth = run.truth["contact_w"]
    cols, analysis, _ = contact_rows_in_space(run.signals, poses, calib, mode=per)
    x = (poses.p_mm - poses.p_mm[0]) @ poses.rotations[0].apply([1.0, 0.0, 0.0])
    try:
        flat, flat_run = contact_rows(run.signals, stage_log_from_arrays(
            t, x, source="one-axis travel", max_gap_s=MAX_GAP_S), calib, None, per)
        without = point_errors(placed_in_world(flat, flat_run, poses, 0.0), truth)
    except ValueError:  # the base's own travel too short to align or to place
        without = np.full(1, math.inf)
    return {"seed": seed, "with": point_errors(cols, truth), "without": without,
            "offset_err_s": analysis.offset_s - run.offset_s,
            "whisk_deg": float(run.info["whisk_deg"])}


def _stats(e: np.ndarray) -> str:
    if not e.size:
        return "n 0"
    return f"median {np.median(e):.2f} mm, p95 {np.percentile(e, 95):.2f} mm (n {e.size})"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="camwhisker dev whisk-bench", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--kind", choices=("wall", "cylinder"), default="wall")
    p.add_argument("--seeds", default="10-19", help="seeds (held out: 10-19; tuning: 0-9)")
    p.add_argument("--per", choices=("frame", "pause"), default="pause",
                   help="contact from each frame or from each pause's medians")
    args = p.parse_args(argv)
    calib = read_calibration(CALIB_PATH)
    t0, rows = time.perf_counter(), []
    for seed in seed_list(args.seeds):
        r = run_whisk(args.kind, seed, calib, args.per)
        rows.append(r)
        print(f"{args.kind} {seed}: whisk {r['whisk_deg']:.1f} deg; with the model "
              f"{_stats(r['with'])}; without {_stats(r['without'])}; offset "
              f"{1000 * r['offset_err_s']:+.1f} ms", flush=True)
    both = {k: np.concatenate([r[k] for r in rows]) for k in ("with", "without")}
    worst = max(abs(r["offset_err_s"]) for r in rows)
    print(f"all ({args.kind}, seeds {args.seeds}, per {args.per}): with the turning model "
          f"{_stats(both['with'])}; one-axis travel {_stats(both['without'])}; clock offset "
          f"error at most {1000 * worst:.1f} ms; {time.perf_counter() - t0:.0f} s")
    return 0
