"""Per-frame contact on simulated runs, paused and continuous: the done-when numbers.

For each protocol (the paper's pauses, or a continuous sweep at a given base
speed) every run of every contact kind goes through
:func:`~camwhisker.contact.pipeline.contact_rows` in frame mode with the clock
offset estimated; the frames in contact with true phi >= 2 deg are scored:
the share where GM, MF and Z are defined, the rigid GM error, the ROC AUC of
eq. (11)'s Z for compliant or slipping contact against rigid, and the clock
offset's error in frames with its reported standard error.
"""

from __future__ import annotations

import numpy as np

from camwhisker.contact.pipeline import Calibration, contact_rows
from camwhisker.contact.stage import stage_log_from_arrays
from camwhisker.contact.zscore import roc_auc
from camwhisker.sim.mechanics.experiment import continuous_protocol, simulate_runs

__all__ = ["FRAME_KINDS", "PHI_MIN_DEG", "frame_runs", "evaluate_frames", "score_frames",
           "format_frames"]

FRAME_KINDS = ("rigid", "compliant", "slide-box", "slide-circle")
# The issue's population: frames in contact with phi >= 2 deg.
PHI_MIN_DEG = 2.0


def frame_runs(seed: int, speed_mm_s: float | None, **sim) -> list:
    """(kind, run) of every run scored for one protocol (``speed_mm_s`` None: the paper's
    pauses), in :data:`FRAME_KINDS` order."""
    kw = dict(sim)
    if speed_mm_s is not None:
        kw["protocol"] = continuous_protocol(speed_mm_s)
    return [(kind, run) for kind in FRAME_KINDS for run in simulate_runs(kind, seed, **kw)]


def evaluate_frames(calib: Calibration, seed: int, speed_mm_s: float | None, **sim) -> dict:
    """Scores of one protocol (``speed_mm_s`` None: the paper's pauses) on runs of ``seed``,
    their signals as the simulator writes them."""
    runs = frame_runs(seed, speed_mm_s, **sim)
    return score_frames(calib, runs, [run.signals for _, run in runs], speed_mm_s)


def score_frames(calib: Calibration, runs: list, signals: list, speed_mm_s: float | None) -> dict:
    """Scores of ``runs`` ((kind, run) pairs, :func:`frame_runs`) from ``signals`` (one
    signal table per run, on the run's camera clock)."""
    parts, offset_err, offset_se = [], [], []
    for (kind, run), sig in zip(runs, signals, strict=True):
        log = stage_log_from_arrays(run.stage["t_s"], run.stage["x_mm"])
        cols, a = contact_rows(sig, log, calib)
        frame_s = float(np.median(np.diff(sig["t_s"])))
        offset_err.append((a.offset_s - run.offset_s) / frame_s)
        offset_se.append(a.offset_se_s / frame_s)
        tr = run.truth
        sel = (tr["in_contact"] > 0) & (tr["phi_deg"] >= PHI_MIN_DEG)
        parts.append({
            "gm": cols["r_gm_mm"][sel], "mf": cols["r_mf_mm"][sel], "z": cols["z_score"][sel],
            "r": tr["r_mm"][sel], "slip": np.asarray(tr["slipping"], bool)[sel],
            "kind": np.full(int(sel.sum()), kind),
        })
    p = {k: np.concatenate([q[k] for q in parts]) for k in parts[0]}
    rigid = p["kind"] == "rigid"
    err = (p["r"] - p["gm"])[rigid & np.isfinite(p["gm"])]
    positive = (p["kind"] == "compliant") | p["slip"]
    use = positive | rigid
    oe = np.abs(offset_err)
    return {
        "speed_mm_s": speed_mm_s, "n": int(p["gm"].size),
        "gm_defined": float(np.isfinite(p["gm"]).mean()),
        "mf_defined": float(np.isfinite(p["mf"]).mean()),
        "z_defined": float(np.isfinite(p["z"]).mean()),
        "gm_mean_mm": float(np.mean(err)), "gm_sd_mm": float(np.std(err)),
        "z_auc": roc_auc(p["z"][use], positive[use]),
        "offset_within_1": int(np.sum(oe <= 1.0)), "runs": len(oe),
        "offset_median_frames": float(np.median(oe)), "offset_max_frames": float(np.max(oe)),
        "offset_se_frames": float(np.nanmedian(offset_se)) if np.isfinite(offset_se).any()
        else float("nan"),
    }


def format_frames(rows: list[dict]) -> list[str]:
    """One line per protocol."""
    lines = [f"{'protocol':<14}{'n':>7}{'GM def':>8}{'MF def':>8}{'Z def':>7}{'GM mean':>9}"
             f"{'GM sd':>7}{'Z AUC':>7}{'off<=1fr':>10}{'off med':>9}{'off max':>9}{'se med':>8}"]
    for r in rows:
        name = "paused" if r["speed_mm_s"] is None else f"{r['speed_mm_s']:g} mm/s"
        lines.append(
            f"{name:<14}{r['n']:>7}{r['gm_defined']:>8.3f}{r['mf_defined']:>8.3f}"
            f"{r['z_defined']:>7.3f}{r['gm_mean_mm']:>9.2f}{r['gm_sd_mm']:>7.2f}{r['z_auc']:>7.3f}"
            f"{r['offset_within_1']:>6d}/{r['runs']:<3d}{r['offset_median_frames']:>9.2f}"
            f"{r['offset_max_frames']:>9.2f}{r['offset_se_frames']:>8.2f}")
    return lines
