"""The learned estimator on our sensor, beside GM, MF and fused.

Per noise level (:data:`~camwhisker.sim.mechanics.experiment.NOISE_LEVELS`: the paper's, our
front end's), as contact-bench does: calibrate GM and MF on the simulated rigid runs of
``seed``, and train the learned estimator on the frames of the same runs
(:mod:`camwhisker.learn.sensor`: phi, dz, theta, base travel -> the stage log's r). Then
every estimator runs per frame (``contact --per frame``) on the held-out runs of
``seed + 1``: rigid pegs, compliant pegs, the box (it slips) and the bottle (it slips, swept
from both sides). Each scene is scored on the same frames for every estimator: in contact,
true phi >= 2 deg (:data:`~camwhisker.bench.frames.PHI_MIN_DEG`), every estimate defined.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from camwhisker.bench.contact import _log, calibrate_simulated
from camwhisker.bench.frames import PHI_MIN_DEG
from camwhisker.contact.pipeline import contact_rows
from camwhisker.learn.sensor import (
    SENSOR_INPUTS,
    frame_inputs,
    learned_r_mm,
    log_r_mm,
    run_tables,
    sensor_columns,
)
from camwhisker.sim.mechanics.experiment import NOISE_LEVELS, simulate_runs

__all__ = ["SCENES", "PIPELINE", "VARIANTS", "SensorOptions", "variant_name", "prepared_runs",
           "training_tables", "score_scene", "run_sensor", "format_sensor"]  # fmt: skip

#: Scene shown -> simulator kind of the held-out runs.
SCENES = {"rigid": "rigid", "compliant": "compliant", "box (slips)": "slide-box",
          "bottle (slips)": "slide-circle"}  # fmt: skip
#: The pipeline's estimators compared, by their contact table column.
PIPELINE = {"GM": "r_gm_mm", "MF": "r_mf_mm", "fused": "r_fused_mm"}
#: Input sets trained and compared: all of the issue's (theta included), without theta
#: (it is constant over calibration runs, which push one way), and without the stage's travel.
VARIANTS = (SENSOR_INPUTS, ("phi_deg", "dz_mm", "dx_mm"), ("phi_deg", "dz_mm"))


@dataclass(frozen=True)
class SensorOptions:
    #: 0.5 s at the simulator's 30 frames/s: about the span of the frame pipeline's +-0.2 s
    #: line, short enough that dropouts (1 % of frames) leave most frames predicted.
    window: int = 15
    epochs: int = 30
    #: Every this many-th segment of each run is held out to choose the epoch (all radii
    #: stay in training; a whole run held out would take its radius away).
    validation_every: int = 5
    variants: tuple[tuple[str, ...], ...] = VARIANTS
    seed: int = 0
    #: The model kind (:data:`~camwhisker.learn.train.KINDS`): conv, which beat knn here
    #: (knn cannot interpolate between the few radii of the calibration runs).
    kind: str = "conv"


def variant_name(inputs: tuple[str, ...]) -> str:
    """A short name of an input set: ``phi,dz,theta,dx``."""
    short = {"phi_deg": "phi", "dz_mm": "dz", "theta_cos": "theta", "theta_sin": "theta",
             "dx_mm": "dx"}  # fmt: skip
    return ",".join(dict.fromkeys(short[c] for c in inputs))


def prepared_runs(calib, kind: str, seed: int, noise, calibration: bool) -> list[dict]:
    """Per run of ``kind``: its contact table (per frame), inputs, truth and, for
    calibration runs, the stage log's r per frame."""
    out = []
    for run in simulate_runs(kind, seed, noise=noise):
        log = _log(run, calibration)
        cols, a = contact_rows(run.signals, log, calib)
        out.append({"name": f"{kind}:{run.name}", "cols": cols, "truth": run.truth,
                    "theta_deg": run.signals["theta_deg"],
                    "inputs": frame_inputs(cols, run.signals["theta_deg"]),
                    "log_r": log_r_mm(log, run.signals["t_s"], a.offset_s) if calibration
                    else None})  # fmt: skip
    return out


def training_tables(runs: list[dict], inputs: tuple[str, ...], opts: SensorOptions):
    """(training, validation) tables from calibration runs (:func:`prepared_runs`): frames in
    contact (truth) with every input defined, target the stage log's r; every
    ``validation_every``-th segment of each run held out."""
    columns = sensor_columns(inputs)
    training, validation = [], []
    for run in runs:
        tables = run_tables(run["inputs"], columns, run["name"], opts.window, run["log_r"],
                            keep=run["truth"]["in_contact"] > 0)  # fmt: skip
        for k, t in enumerate(tables):
            held = k % opts.validation_every == opts.validation_every - 1
            (validation if held else training).append(t)
    return training, validation


def _errors(err: np.ndarray) -> dict:
    return {"rmse_mm": float(np.sqrt(np.mean(err**2))) if err.size else np.nan,
            "median_abs_mm": float(np.median(np.abs(err))) if err.size else np.nan}  # fmt: skip


def score_scene(runs: list[dict], estimates: dict[str, list[np.ndarray]]) -> dict:
    """One scene's frames scored and each estimator's r errors (mm) on them: frames in
    contact with true phi >= 2 deg where every estimate is defined. ``estimates``: name ->
    per run an r per frame."""
    sel = [(r["truth"]["in_contact"] > 0) & (r["truth"]["phi_deg"] >= PHI_MIN_DEG)
           for r in runs]  # fmt: skip
    truth = np.concatenate([r["truth"]["r_mm"][s] for r, s in zip(runs, sel, strict=True)])
    est = {k: np.concatenate([e[s] for e, s in zip(v, sel, strict=True)])
           for k, v in estimates.items()}  # fmt: skip
    same = np.isfinite(truth) & np.all([np.isfinite(e) for e in est.values()], axis=0)
    return {"n": int(same.sum()), "n_contact": int(truth.size),
            **{k: _errors((truth - e)[same]) for k, e in est.items()}}  # fmt: skip


def run_sensor(seed: int, opts: SensorOptions = SensorOptions(), out=None,
               progress: bool = False) -> dict:  # fmt: skip
    """Train every variant and score every scene at each noise level; with ``out``, each
    model is saved as a model directory ``out/<level>/<variant>``.
    Returns {level: {"noise", "train": {variant: summary}, "scenes": {scene: scores}}}."""
    from camwhisker.learn.modeldir import Model, save_model
    from camwhisker.learn.train import TrainOptions, train

    result = {}
    for level, noise in NOISE_LEVELS.items():
        calib = calibrate_simulated(seed, noise=noise)
        cal_runs = prepared_runs(calib, "rigid", seed, noise, calibration=True)
        scenes = {s: prepared_runs(calib, k, seed + 1, noise, False) for s, k in SCENES.items()}
        estimates = {s: {} for s in scenes}
        summaries = {}
        for inputs in opts.variants:
            name, columns = variant_name(inputs), sensor_columns(inputs)
            training, validation = training_tables(cal_runs, inputs, opts)
            topts = TrainOptions(kind=opts.kind, epochs=opts.epochs, seed=opts.seed)
            # no refit on the validation segments: measured, it moved the table both ways
            # (phi, dz: rigid 5.55 -> 5.88 mm, box 4.81 -> 4.32 mm at the paper's noise)
            trained = train(training, validation, columns, opts.window, topts, progress)
            summaries[name] = trained.summary
            model = Model(trained.net, columns, opts.window, trained.norm, {})
            if out is not None:
                from pathlib import Path

                save_model(Path(out) / level / name.replace(",", "-"), trained.net, columns,
                           opts.window, trained.norm, trained.arch, trained.summary)
            for s, runs in scenes.items():
                estimates[s][f"learned {name}"] = [learned_r_mm(model, r["cols"], r["theta_deg"])
                                                   for r in runs]  # fmt: skip
        for s, runs in scenes.items():
            for k, c in PIPELINE.items():
                estimates[s][k] = [r["cols"][c] for r in runs]
        result[level] = {"noise": noise, "train": summaries,
                         "scenes": {s: score_scene(runs, estimates[s])
                                    for s, runs in scenes.items()}}  # fmt: skip
    return result


def format_sensor(result: dict, seed: int, opts: SensorOptions) -> str:
    """A Markdown table: per noise level and scene, each estimator's RMSE / median |err|."""
    names = list(next(iter(next(iter(result.values()))["scenes"].values())))[2:]
    lines = ["| noise | scene | frames | " + " | ".join(names) + " |",
             "|---" * (3 + len(names)) + "|"]
    for level, r in result.items():
        for scene, s in r["scenes"].items():
            cells = " | ".join(f"{s[k]['rmse_mm']:.2f} / {s[k]['median_abs_mm']:.2f}"
                               for k in names)  # fmt: skip
            lines.append(f"| {level} | {scene} | {s['n']}/{s['n_contact']} | {cells} |")
        train_s = [f"{r['train'][k[len('learned '):]]['train_s']:.0f} s"
                   if k.startswith("learned ") else "" for k in names]  # fmt: skip
        lines.append(f"| {level} | training time | | " + " | ".join(train_s) + " |")
    chose = "; ".join(f"{level} {v}: " + (f"k {t['k']}" if "k" in t else
                                          f"epoch {t['best_epoch']} of {t['epochs_run']}")
                      for level, r in result.items() for v, t in r["train"].items())
    rows = ", ".join(f"{v} {t['training_rows']}"
                     for v, t in next(iter(result.values()))["train"].items())
    lines += ["", f"Cells: r RMSE / median |error| (mm), per frame (r - r_hat), on the same "
              f"frames for every estimator: frames scored / frames in contact with true phi >= "
              f"{PHI_MIN_DEG:g} deg. GM, MF, fused: contact --per frame. Calibration and "
              f"training: rigid runs of seed {seed}; scored: runs of seed {seed + 1}. "
              f"Learned: window {opts.window} frames, {opts.kind}"
              + (f" 32, <= {opts.epochs} epochs" if opts.kind == "conv" else "")
              + f" (chosen on validation: {chose}); training rows at the first level: {rows}."]
    return "\n".join(lines)
