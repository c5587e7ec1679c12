"""The whole mission on a filmed stage experiment, checked against the simulator's truth.

:func:`run_chain` takes a folder made by
:func:`camwhisker.sim.render.experiment.render_experiment` (videos, stage logs on
the stage's clock, truth) and runs what a user runs, in order:

1. ``batch``: the vision front end on every video (in parallel processes);
2. ``calibrate``: C of eq. (8), sigma_GM(phi) and the MF table from the
   calibration runs, clock offsets estimated;
3. ``contact --per pause``: contact tables (docs/sensor.md section 7) for every run,
   each row the estimate of its stage pause (the paper's pause medians; ``experiment``'s
   default too, where ``contact`` alone defaults to each frame's own);
4. evaluation against the simulator's truth, and the Fig. 7A, 8 and 9 plots.

Every number of the printed summary is in ``summary.json`` beside the CSVs
and PNGs that produced it.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from camwhisker import __version__
from camwhisker.bench.contact import BAD_GM_ERROR_MM, evaluate_run, pool, summary
from camwhisker.contact.calibrate import write_calibration
from camwhisker.contact.fusion import gm_error_score
from camwhisker.contact.pipeline import contact_rows
from camwhisker.contact.stage import read_stage_log
from camwhisker.contact.zscore import flag_rates, roc_auc
from camwhisker.files import jsonfile
from camwhisker.files.atomic import atomic_path
from camwhisker.files.tables import read_columns, write_csv
from camwhisker.io.signals import read_signal_table
from camwhisker.run.experiment import ExperimentError, Recording, batch_runs, calibrate_runs
from camwhisker.sensor.file import load_sensor
from camwhisker.sim.mechanics.experiment import scene_by_name
from camwhisker.sim.render.experiment import read_experiment
from camwhisker.sim.render.scenarios import PoseTrack
from camwhisker.sim.render.video import sidecar_paths

__all__ = ["ChainError", "run_chain", "format_summary", "LOW_Z", "FLAG_Z", "SHAPE_TOL_MM",
           "TERMS"]

#: The paper's reading of Z: below 0.5 an expected deviation (trusted) ...
LOW_Z = 0.5
#: ... above 1 a doubtful estimate (flagged).
FLAG_Z = 1.0
#: Box and bottle points with a low score must lie this close to the profile.
SHAPE_TOL_MM = 3.0
#: The paper's data points: each stage pause's medians.
CONTACT_PER = "pause"
#: The flags the summary scores, as it names them; gm_error is the one to use.
FLAG_NAMES = {"z_score": "eq. 11 Z > 1", "z_combined": "z_combined > 1",
              "gm_error": "recommended"}


#: Every term of the summary, defined once: printed above it and kept in summary.json.
TERMS = {
    "r": "contact distance along the whisker from its base (mm); an error is r - r_hat at "
         "a stage pause (the median of its frames)",
    "GM": "r from the stage's travel since first contact and the tilt phi (eq. 8, or the "
          "beam model where it fits the calibration better)",
    "MF": "r from phi and the axial deflection dz, looked up in the calibration's table "
          "(eqs. 9-10); fused: GM and MF combined by their spreads",
    "Z": "eq. (11): how far GM and MF disagree, in units of GM's spread at that phi",
    "trusted": f"Z < {LOW_Z:g}: GM and MF agree",
    "flagged": f"Z > {FLAG_Z:g}: the estimate is shown as doubtful",
    "bad": f"a GM estimate more than {BAD_GM_ERROR_MM:g} mm off (the paper's GM failure); "
           "every other one is good",
    "hit": "share of the bad estimates that are flagged",
    "false flags": "share of the good estimates that are flagged",
    "AUC": "chance that a bad estimate has a higher Z than a good one (1: Z tells them "
           "apart always, 0.5: no better than chance)",
    "recommended": "the flag to use: GM may be off by more than E where |gm_bias_mm| (the "
                   "fusion's estimate of GM's bias, a contact table column) exceeds E less "
                   "MF's per-contact systematic error (the calibration's floor, 2 mm)",
    "n/a": "nothing to compute it on (no bad estimate, or no point)",
    "separation": "(summary.json only) Z against the cause rather than the error: slipping "
                  "or compliant contact against rigid contact held still",
}


class ChainError(ExperimentError):
    """A stage of the chain failed; the message names the stage and the inputs."""


def _front_end_errors(signals: dict, truth: PoseTrack) -> dict:
    ok = np.asarray(signals["ok"], bool)
    n = min(ok.size, len(truth))
    ok = ok[:n]
    e_phi = (signals["phi_deg"][:n] - truth.phi_deg[:n])[ok]
    e_dz = (signals["dz_mm"][:n] - truth.dz_mm[:n])[ok]
    return {"frames": int(n), "ok": int(ok.sum()), "e_phi": e_phi, "e_dz": e_dz}


def _rms(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if x.size else math.nan


def run_chain(experiment: Path, out: Path, jobs: int = 2, progress: bool = True) -> dict:
    """Run batch, calibrate and contact on a filmed experiment; evaluate; plot.

    Returns the summary (also written to ``out/summary.json``).
    """
    experiment, out = Path(experiment), Path(out)
    runs = read_experiment(experiment)
    sensor_file = sidecar_paths(runs[0].video)["sensor"]
    sensor = load_sensor(sensor_file if sensor_file.is_file() else None)
    timings = {}
    # The user's pipeline (run.experiment) on the filmed runs, named by their videos.
    recordings = [Recording(r.video.stem, r.video, r.stage, r.role == "calibration")
                  for r in runs]  # fmt: skip
    if not any(r.calibration for r in recordings):
        raise ChainError(f"{experiment}: no calibration runs")
    tables, timings["batch"] = batch_runs(recordings, sensor, out, jobs, progress)
    signals = {key: read_signal_table(path) for key, path in tables.items()}
    logs = {r.video.stem: read_stage_log(r.stage) for r in runs}

    t0 = time.perf_counter()
    calib, cal_data = calibrate_runs(recordings, sensor, tables, signals, logs,
                                     f"camwhisker dev chain {experiment}")  # fmt: skip
    write_calibration(out / "calib.toml", calib)
    timings["calibrate"] = {"seconds": time.perf_counter() - t0}

    t0 = time.perf_counter()
    ev, front_end = _contact(out, runs, calib, signals, logs)
    timings["contact"] = {"seconds": time.perf_counter() - t0}
    result = {"terms": TERMS, **_evaluate(calib, ev, front_end)}
    result["timings"] = timings
    result["provenance"] = {
        "camwhisker_version": __version__,
        "experiment": str(experiment),
        "out": str(out),
        "sensor": sensor.source,
        "calibration": str(out / "calib.toml"),
        "contact_per": CONTACT_PER,
    }

    # Plots, next to the CSVs that produced them.
    t0 = time.perf_counter()
    _plots(out, calib, cal_data, ev, runs)
    timings["plots"] = {"seconds": time.perf_counter() - t0}
    with atomic_path(out / "summary.json") as tmp:
        tmp.write_text(jsonfile.dumps(result, indent=2) + "\n")
    return result


def _contact(out: Path, runs, calib, signals: dict, logs: dict) -> tuple[dict, list]:
    """Steps 3 and 4: contact tables for every run, evaluated against the truth.

    Returns the pooled evaluation by role and the front end's errors by run.
    """
    evaluations: dict[str, list] = {}
    front_end = []
    for i, r in enumerate(runs):
        key = r.video.stem
        cols, _ = contact_rows(signals[key], logs[key], calib, mode=CONTACT_PER)
        write_csv(out / "contact" / f"{r.video.stem}.csv", cols)
        truth = read_columns(r.contact_truth)
        ev = evaluate_run(
            calib, signals[key], logs[key], truth, scene_by_name(r.kind, r.name), r.offset_s, i
        )
        evaluations.setdefault(r.role, []).append(ev)
        front_end.append(
            _front_end_errors(signals[key], PoseTrack.read_csv(sidecar_paths(r.video)["truth"]))
        )
    return {role: pool(parts) for role, parts in evaluations.items()}, front_end


def _flags(p: dict, defined, calib) -> dict:
    """Eq. 11 as printed (Z > 1), z_combined > 1 and the recommended flag
    (:func:`~camwhisker.contact.fusion.gm_error_score`) against GM errors over the summary's
    bad (TERMS["bad"], the paper's 15 mm) and over 3 sigma_GM."""
    err = np.abs(p["r_true_mm"] - p["r_gm_mm"])
    # The summary's one definition of a bad estimate (TERMS["bad"]).
    bad = err > BAD_GM_ERROR_MM
    z = np.where(defined, p["z_score"], np.nan)
    hit, false = flag_rates(z, bad, FLAG_Z)
    out = {"n": int(defined.sum()), "n_bad": int((bad & defined).sum()), "auc": roc_auc(z, bad),
           "hit": hit, "false_flags": false}
    floor = calib.mf_bias_floor_mm
    for level, limit in (("15mm", BAD_GM_ERROR_MM), ("3sigma", 3.0 * p["sigma_gm_mm"])):
        off = err > limit
        scores = {"z_score": (z, FLAG_Z),
                  "z_combined": (np.where(defined, p["z_combined"], np.nan), FLAG_Z),
                  "gm_error": (np.where(defined, gm_error_score(p["gm_bias_mm"], limit, floor),
                                        np.nan), 0.0)}  # fmt: skip
        out[level] = {"n_bad": int((off & defined).sum()),
                      **{name: dict(zip(("hit", "false_flags"), flag_rates(s, off, t),
                                        strict=True)) for name, (s, t) in scores.items()}}
    return out


def _evaluate(calib, ev: dict, front_end: list) -> dict:
    eq8 = calib.gm.alternatives["eq8"]
    lo, hi = eq8.ci["c"]
    out = {
        "C": eq8.params["c"],
        "C_ci95": [lo, hi],
        "gm_model_used": calib.gm.kind,
        "front_end": {
            "frames": sum(f["frames"] for f in front_end),
            "ok": sum(f["ok"] for f in front_end),
            "phi_rmse_deg": _rms(np.concatenate([f["e_phi"] for f in front_end])),
            "dz_rmse_mm": _rms(np.concatenate([f["e_dz"] for f in front_end])),
        },
        "roles": {role: summary(e) for role, e in ev.items()},
    }
    # Rigid, non-slipping contact outside the calibration: box and bottle before they slide.
    held = [e for role, e in ev.items() if role in ("box", "bottle")]
    if held:
        h = pool(held)
        stuck = ~h["slipping"] & np.isfinite(h["r_true_mm"]) & np.isfinite(h["r_gm_mm"])
        err = (h["r_true_mm"] - h["r_gm_mm"])[stuck]
        out["rigid_stuck_gm"] = {
            "n": int(err.size),
            "mean_mm": float(np.mean(err)),
            "sd_mm": float(np.std(err, ddof=1)) if err.size > 1 else math.nan,
        }
    # Does Z separate slipping and compliant samples from good ones?
    roles = [role for role in ev if role != "calibration"]
    if roles:
        p = pool([ev[role] for role in roles])
        defined = (
            np.isfinite(p["r_true_mm"]) & np.isfinite(p["r_gm_mm"]) & np.isfinite(p["r_mf_mm"])
        )
        compliant = np.concatenate(
            [np.full(ev[r]["r_true_mm"].size, r == "compliant") for r in roles]
        )
        doubtful = np.asarray(p["slipping"], bool) | compliant
        out["separation"] = {
            "n_doubtful": int((doubtful & defined).sum()),
            "n_good": int((~doubtful & defined).sum()),
        }
        for name in ("z_score", "z_combined"):
            s = np.where(defined, p[name], np.nan)
            hit, false = flag_rates(s, doubtful, FLAG_Z)
            out["separation"][name] = {"auc": roc_auc(s, doubtful), "hit": hit, "false": false}
        out["z_flags"] = _flags(p, defined, calib)
    # Shapes: low-score points of the box and bottle against the true profile.
    out["shapes"] = {}
    for role in ("box", "bottle"):
        if role not in ev:
            continue
        e = ev[role]
        drawn = np.isfinite(e["profile_dist_mm"])
        # Past the MF table's largest radius (the box's face rises beyond it): MF a lower bound.
        past = drawn & np.asarray(e["mf_past_top"], bool)
        inside = drawn & ~past
        low = (e["z_score"] < LOW_Z) & drawn
        d = e["profile_dist_mm"][low]
        # Fig. 9's slip stretch: slipping points with a defined score, and those shown doubtful.
        slip = np.asarray(e["slipping"], bool) & np.isfinite(e["z_score"])
        flagged = e["z_score"][slip] > FLAG_Z
        out["shapes"][role] = {
            "n_low_z": int(low.sum()),
            "max_dist_mm": float(d.max()) if d.size else math.nan,
            # Every point, each from the fused r: the shape as drawn.
            "n_points": int(drawn.sum()),
            "max_dist_all_mm": float(e["profile_dist_mm"][inside].max()) if inside.any()
            else math.nan,
            "n_past_mf_table": int(past.sum()),
            "max_dist_past_mm": float(e["profile_dist_mm"][past].max()) if past.any()
            else math.nan,
            "within_tol": int((d <= SHAPE_TOL_MM).sum()),
            "n_slipping": int(slip.sum()),
            "slipping_flagged": int(flagged.sum()),
        }
    return out


def _plots(out: Path, calib, cal_data: dict, ev: dict, runs) -> None:
    from camwhisker.contact.plots import plot_error_boxes, plot_gm_model, plot_shapes

    how = f"camwhisker dev chain, {len(runs)} filmed runs"  # the figure adds the version
    plot_gm_model(calib, cal_data, out / "fig7a_gm_model.png", "Fig. 7A: " + how)
    # Rigid contact held out of the calibration (the MF table holds the calibration
    # samples themselves, so their MF error would be zero): box and bottle before they slide.
    held = [ev[role] for role in ("box", "bottle") if role in ev]
    boxes = {}
    if held:
        h = pool(held)
        stuck = ~np.asarray(h["slipping"], bool)
        boxes["rigid"] = {k: v[stuck] for k, v in h.items()}
    if "compliant" in ev:
        boxes["compliant"] = ev["compliant"]
    plot_error_boxes(
        boxes, out / "fig8_errors.png", "Fig. 8: rigid = box and bottle before they slide; " + how
    )
    shapes = {r.role: r for r in runs if r.role in ("box", "bottle")}
    if shapes:
        from camwhisker.bench.percepts import fitted_outline

        outlines = {role: scene_by_name(r.kind, r.name).outline() for role, r in shapes.items()}
        fitted = {role: fitted_outline(ev[role]) for role in shapes}
        plot_shapes({role: ev[role] for role in shapes}, outlines, out / "fig9_shapes.png",
                    "Fig. 9: " + how, fitted)


def _num(x: float, fmt: str) -> str:
    """``x`` formatted, or "n/a" where it is not a number (TERMS["n/a"])."""
    return format(x, fmt) if x is not None and math.isfinite(x) else "n/a"


def format_summary(s: dict) -> str:
    """The short summary a person reads after the chain: its terms first, each once."""
    width = max(len(t) for t in TERMS if t != "separation")
    lines = ["terms:"] + [f"  {t:<{width}}  {d}" for t, d in TERMS.items() if t != "separation"]
    fe = s["front_end"]
    lines += [
        f"GM: C of eq. (8) = {s['C']:.1f} (95 % CI {s['C_ci95'][0]:.1f}-{s['C_ci95'][1]:.1f});"
        f" model used: {s['gm_model_used']}",
        f"front end: {fe['ok']} of {fe['frames']} frames ok; phi RMSE "
        f"{_num(fe['phi_rmse_deg'], '.3f')} deg, dz RMSE {_num(fe['dz_rmse_mm'], '.4f')} mm",
        f"contact tables per {s['provenance']['contact_per']} (as `contact --per "
        f"{s['provenance']['contact_per']}`); errors (mm) per role, the calibration's "
        "in-sample (MF's table holds its pauses), over the pauses with GM and MF (of those "
        "with GM, as Fig. 7A counts them):",
        f"  {'role':<12}{'pauses':>10}{'GM RMSE':>9}{'GM mean':>9}{'MF RMSE':>9}"
        f"{'fused RMSE':>12}{'bad':>5}{'hit':>6}{'false flags':>13}",
    ]
    for role, r in s["roles"].items():
        pauses = f"{r['n']} of {r['n_gm']}"
        lines.append(
            f"  {role:<12}{pauses:>10}{_num(r['gm_rmse_mm'], '.2f'):>9}"
            f"{_num(r['gm_mean_mm'], '.2f'):>9}{_num(r['mf_rmse_mm'], '.2f'):>9}"
            f"{_num(r['fused_rmse_mm'], '.2f'):>12}{r['n_bad']:>5}"
            f"{_num(r['z_score_hit'], '.2f'):>6}{_num(r['z_score_false'], '.2f'):>13}"
        )
    if "rigid_stuck_gm" in s:
        g = s["rigid_stuck_gm"]
        lines.append(
            f"rigid contact held still (box and bottle before they slide): GM error mean "
            f"{_num(g['mean_mm'], '.2f')} mm, sd {_num(g['sd_mm'], '.2f')} mm ({g['n']} pauses)"
        )
    if "z_flags" in s:
        z = s["z_flags"]
        lines.append(
            f"every role but the calibration: {z['n_bad']} bad of {z['n']} pauses; Z's AUC "
            f"{_num(z['auc'], '.3f')}, hit {_num(z['hit'], '.2f')}, false flags "
            f"{_num(z['false_flags'], '.2f')} (the paper's: 0.26)"
        )
        for level, what in (("15mm", f"GM off by > {BAD_GM_ERROR_MM:g} mm (bad)"),
                            ("3sigma", "GM off by > 3 sigma_GM")):  # fmt: skip
            f = z[level]
            lines.append(
                f"  {what}, {f['n_bad']} of {z['n']}: hit / false "
                "flags: " + "; ".join(f"{FLAG_NAMES[k]} {_num(v['hit'], '.2f')} / "
                                      f"{_num(v['false_flags'], '.2f')}"
                                      for k, v in f.items() if k != "n_bad"))
    for role, sh in s["shapes"].items():
        trusted = (f"{sh['n_low_z']} trusted, {sh['within_tol']} of them within "
                   f"{SHAPE_TOL_MM:g} mm (max {_num(sh['max_dist_mm'], '.2f')} mm)"
                   if sh["n_low_z"] else "none trusted")
        past = (f" ({sh['n_past_mf_table']} past the MF table's largest radius: within "
                f"{_num(sh['max_dist_past_mm'], '.2f')} mm)" if sh["n_past_mf_table"] else "")
        lines.append(
            f"{role} shape (Fig. 9): {sh['n_points']} points, those inside the MF table within "
            f"{_num(sh['max_dist_all_mm'], '.2f')} mm of the true profile{past}; {trusted}; "
            f"{sh['slipping_flagged']} of {sh['n_slipping']} slipping points flagged"
        )
    t = s["timings"]
    lines.append(
        f"time: batch {t['batch']['seconds']:.1f} s ({t['batch']['frames']} frames, "
        f"{t['batch']['reused']} tables reused; "
        f"{_num(t['batch']['frames_per_s_per_core'], '.0f')} frames/s per core incl. decode), "
        f"calibrate {t['calibrate']['seconds']:.1f} s, contact {t['contact']['seconds']:.1f} s, "
        f"plots {t['plots']['seconds']:.1f} s"
    )
    return "\n".join(lines)
