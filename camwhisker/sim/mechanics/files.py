"""Writing simulated stage runs to files: stage log, signal table, truth, manifest."""

from __future__ import annotations

import datetime as _dt
from pathlib import Path

from camwhisker import __version__
from camwhisker.files.atomic import atomic_write_text
from camwhisker.files.tables import write_csv
from camwhisker.files.tomlfile import toml_string
from camwhisker.io.forcelog import ForceLog, write_force_log
from camwhisker.sim.mechanics.experiment import StageRun

__all__ = ["write_runs", "write_texture_run"]

TRUTH_COLUMNS = ("t_s", "x_mm", "dx_mm", "phi_deg", "dz_mm", "r_mm", "contact_x_mm",
                 "contact_y_mm", "in_contact", "slipping")


def write_runs(runs: list[StageRun], out_dir: str | Path, seed: int, command: str = "",
               force_logs: list[tuple[ForceLog, float]] | None = None) -> Path:
    """Write each run as ``<name>_stage.csv``, ``<name>_signals.csv``, ``<name>_truth.csv``,
    and ``<name>_forces.csv`` where ``force_logs`` (one (log, offset_s) per run) are given.

    A manifest ``experiment.toml`` records how the files were made (package
    version, command, seed, time) and each run's true clock offset
    (t_camera = t_stage + offset_s), scene and step count, and the force log's
    true offset (t_camera = t_force + force_offset_s). Returns its path.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    now = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    lines = [
        "# Simulated stage experiment (camwhisker.sim.mechanics); the truth is in *_truth.csv.",
        "[provenance]",
        f"package = {toml_string('camwhisker')}",
        f"version = {toml_string(__version__)}",
        f"created_utc = {toml_string(now)}",
        f"command = {toml_string(command)}",
        f"seed = {int(seed)}",
        f"kind = {toml_string(runs[0].kind if runs else '')}",
        "",
    ]
    for i, run in enumerate(runs):
        stage_cols = {k: run.stage[k] for k in ("t_s", "x_mm", "r_mm", "dz_mm")
                      if k in run.stage}
        write_csv(out / f"{run.name}_stage.csv", stage_cols, digits=10)
        sig = run.signals
        write_csv(out / f"{run.name}_signals.csv",
                  {k: sig[k] for k in ("frame", "t_s", "dz_mm", "phi_deg", "theta_deg", "ok")},
                  digits=8)
        write_csv(out / f"{run.name}_truth.csv", {k: run.truth[k] for k in TRUTH_COLUMNS},
                  digits=8)
        lines += [
            "[[runs]]",
            f"name = {toml_string(run.name)}",
            f"stage = {toml_string(run.name + '_stage.csv')}",
            f"signals = {toml_string(run.name + '_signals.csv')}",
            f"truth = {toml_string(run.name + '_truth.csv')}",
            f"offset_s = {run.offset_s!r}",
            f"scene = {toml_string(repr(run.scene))}",
            f"steps = {int(run.info['n_steps'])}",
            f"x_first_contact_mm = {float(run.info['x_first_contact_mm'])!r}",
        ]
        if force_logs is not None:
            log, force_offset = force_logs[i]
            write_force_log(out / f"{run.name}_forces.csv", log)
            lines += [f"forces = {toml_string(run.name + '_forces.csv')}",
                      f"force_offset_s = {force_offset!r}"]
        lines.append("")
    manifest = out / "experiment.toml"
    atomic_write_text(manifest, "\n".join(lines))
    return manifest


def write_texture_run(run, out_dir: str | Path, command: str = "") -> list[Path]:
    """Write a texture run (:func:`camwhisker.sim.mechanics.texture.simulate_texture`) as
    ``signals.csv`` (docs/sensor.md section 6), ``stage.csv`` (stage clock),
    ``truth.csv`` and ``texture.json`` (how it was made, the surface, speed, frame rate,
    the whisker's mode, the true clock offset); no time stamp, so the same command
    writes the same files. Returns the paths."""
    from camwhisker.files.jsonfile import dumps

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / name for name in ("signals.csv", "stage.csv", "truth.csv", "texture.json")]
    sig = run.signals
    write_csv(paths[0], {k: sig[k] for k in ("frame", "t_s", "dz_mm", "phi_deg", "theta_deg",
                                             "ok")}, digits=8)
    write_csv(paths[1], run.stage, digits=10)
    write_csv(paths[2], run.truth, digits=8)
    record = {"camwhisker": __version__, "command": command, **run.info}
    atomic_write_text(paths[3], dumps(record, indent=1) + "\n")
    return paths
