"""Evaluation of the contact back end on simulated stage experiments: errors, scores, speed.

:func:`calibrate_simulated` calibrates on simulated runs; :func:`evaluate_kind`
runs the pause-level pipeline on the runs of one experiment kind and attaches
the truth; :func:`summary` computes the numbers of issue #4 (RMSE and bias of
GM, MF and fused estimates, AUC and flag rates of both Z scores);
:func:`benchmark` times the vectorised core and prints samples/s beside the error.
"""

from __future__ import annotations

import time

import numpy as np

from camwhisker.calibrate import CalibrationRun, calibrate
from camwhisker.contact.pipeline import Calibration, analyse_run, estimate, pause_estimates
from camwhisker.contact.zscore import flag_rates, roc_auc
from camwhisker.mechanics.experiment import simulate_runs
from camwhisker.stage import stage_log_from_arrays

__all__ = ["BAD_GM_ERROR_MM", "calibrate_simulated", "evaluate_kind", "summary", "benchmark"]

# A GM estimate this far off counts as a failure (the paper's 15 mm).
BAD_GM_ERROR_MM = 15.0


def _log(run, with_r: bool):
    return stage_log_from_arrays(run.stage["t_s"], run.stage["x_mm"],
                                 run.stage.get("r_mm") if with_r else None,
                                 source=f"<{run.kind}:{run.name} stage>")


def calibrate_simulated(seed: int, kind: str = "rigid", **sim) -> Calibration:
    """Calibrate on the simulated runs of ``kind`` ("rigid" or "eq8"); offsets estimated."""
    runs = simulate_runs(kind, seed, **sim)
    cal_runs = [CalibrationRun(r.signals, _log(r, True), f"<{kind}:{r.name} signals>")
                for r in runs]
    calib, _, _ = calibrate(cal_runs, l_w_mm=150.0, command=f"calibrate_simulated({seed})")
    return calib


def evaluate_kind(calib: Calibration, kind: str, seed: int, **sim) -> dict:
    """Pause-level estimates with truth for all runs of ``kind``, pooled.

    Truth per pause (at its middle): r_true_mm, slipping, contact point, the
    distance of (x_hat, y_hat) to the true profile (profile_dist_mm), the
    offset error (offset_err_s), and the run index.
    """
    parts = []
    for i, run in enumerate(simulate_runs(kind, seed, **sim)):
        a = analyse_run(run.signals, _log(run, False))
        e = pause_estimates(calib, a)
        tmid = 0.5 * (a.pauses.t_start_s + a.pauses.t_end_s)
        truth = run.truth
        e["r_true_mm"] = np.interp(tmid, truth["t_s"], truth["r_mm"])
        e["slipping"] = np.interp(tmid, truth["t_s"], truth["slipping"].astype(float)) > 0.5
        e["profile_dist_mm"] = run.scene.profile_distance(e["x_hat_mm"], e["y_hat_mm"])
        e["gm_profile_dist_mm"] = run.scene.profile_distance(
            *_gm_point(e, a.travel_sign))
        e["offset_err_s"] = np.full(tmid.size, a.offset_s - run.offset_s)
        e["run"] = np.full(tmid.size, i)
        parts.append(e)
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _gm_point(e, sign):
    from camwhisker.contact.shape import reconstruct

    return reconstruct(e["x_mm"], e["r_gm_mm"], e["phi_deg"], sign)


def summary(ev: dict) -> dict:
    """Errors and score quality on samples where GM, MF and the truth are all defined."""
    r = ev["r_true_mm"]
    both = np.isfinite(r) & np.isfinite(ev["r_gm_mm"]) & np.isfinite(ev["r_mf_mm"])
    out = {"n": int(both.sum())}
    for name in ("r_gm_mm", "r_mf_mm", "r_fused_mm"):
        err = (r - ev[name])[both]
        key = name[2:-3]
        out[f"{key}_rmse_mm"] = float(np.sqrt(np.mean(err**2))) if err.size else np.nan
        out[f"{key}_mean_mm"] = float(np.mean(err)) if err.size else np.nan
    bad = np.abs(r - ev["r_gm_mm"]) > BAD_GM_ERROR_MM
    out["n_bad"] = int((bad & both).sum())
    for z in ("z_score", "z_combined"):
        s = np.where(both, ev[z], np.nan)
        hit, false = flag_rates(s, bad, 1.0)
        out[f"{z}_auc"] = roc_auc(s, bad)
        out[f"{z}_hit"] = hit
        out[f"{z}_false"] = false
    return out


def benchmark(calib: Calibration, n: int = 100_000, repeats: int = 5, seed: int = 0) -> dict:
    """Time :func:`~camwhisker.contact.pipeline.estimate` on n random samples.

    Returns samples per second and microseconds per sample (best of ``repeats``).
    """
    rng = np.random.default_rng(seed)
    t = calib.mf_table
    k = rng.integers(0, len(t), n)
    phi = t.phi_deg[k] + 0.1 * rng.standard_normal(n)
    dz = t.dz_mm[k] + 0.01 * rng.standard_normal(n)
    dx = np.abs(rng.normal(10.0, 5.0, n)) + 0.1
    x = dx
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        estimate(calib, x, dx, phi, dz, 1.0)
        best = min(best, time.perf_counter() - t0)
    return {"samples": n, "seconds": best, "samples_per_s": n / best,
            "us_per_sample": 1e6 * best / n}
