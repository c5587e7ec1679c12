"""Walls and cylinders in space, filmed: the front end sees what a base moving in space does.

:func:`render_space_experiment` writes a folder that ``camwhisker experiment`` runs as a
user's: eight calibration runs on a one-axis stage (rigid pegs, ``calibration_NAME.mp4``
with ``calibration_NAME.stage.csv`` carrying ``r_mm``), the runs of a wall or cylinder
swept at three heights in space (:mod:`camwhisker.sim.mechanics.space`; ``NAME.mp4``
with ``NAME.pose.csv``), and ``sensor.toml``. Beside them, for checking only: per run
``NAME.contact_truth.csv`` (the true contact point in the world frame, ``px_mm``,
``py_mm``, ``pz_mm``, where in contact) and ``object.json`` (the object, the true clock
offsets). Frame rate and compression as the bundled stage experiment
(:mod:`camwhisker.sim.render.experiment`).

As a rig (``rig=True``, :mod:`camwhisker.run.rig_experiment`'s layout): ``rig.toml`` with
the three heights as sensors on one carrier, per run the carrier's ``RUN.pose.csv``, and
per sensor a folder ``SENSOR/`` with eight calibration runs and its ``RUN.mp4`` (with
``RUN.contact_truth.csv``). The simulated sensors are one build: by default their
calibration runs are one set of films, linked into each sensor's folder (each sensor is
still calibrated from its own folder); ``own_calibration_films`` films a set per sensor
(three times the calibration's rendering). A film already there with its seed is kept:
an interrupted render goes on where it stopped.
"""

from __future__ import annotations

import json
import os
import shutil
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

from camwhisker import __version__
from camwhisker.files.atomic import atomic_write_text
from camwhisker.files.jsonfile import dumps
from camwhisker.files.tables import write_csv
from camwhisker.io.rig import RIG_NAME
from camwhisker.sensor.file import Sensor, dump_sensor
from camwhisker.sim.mechanics import StageProtocol, simulate_runs
from camwhisker.sim.mechanics.space import (
    RIG_SENSORS,
    carrier_poses,
    contact_in_world,
    pose_columns,
    rig_toml,
    simulate_space_sweep,
    truth_in_world,
)
from camwhisker.sim.render.experiment import EXPERIMENT_CRF, EXPERIMENT_FPS, pose_track, render_run
from camwhisker.sim.render.scenarios import NOMINAL_ARTEFACTS, Scenario
from camwhisker.sim.render.video import render_scenario, sidecar_paths

__all__ = ["render_space_experiment", "CALIB_SEED_OFFSET"]

#: The calibration runs' simulation seed, from the experiment's.
CALIB_SEED_OFFSET = 500


#: A rig sensor's calibration runs' simulation seed, from the first sensor's.
RIG_CALIB_SEED_STEP = 1000


def _filmed(video: Path, seed: int) -> bool:
    """A film already made with this seed (its sidecar is written last)."""
    meta = sidecar_paths(video)["meta"]
    try:
        return video.is_file() and json.loads(meta.read_text())["seed"] == seed
    except (OSError, ValueError, KeyError):
        return False


def _render_calibration(args) -> None:
    role, run, dest, fps, artefacts, seed = args
    stem = f"{role}_{run.name}"  # a peg's name has a dot (r22.5): no with_suffix
    if not (_filmed(dest / f"{stem}.mp4", seed) and (dest / f"{stem}.contact_truth.csv")
            .is_file()):  # fmt: skip
        render_run(args)


def _link_calibration(dest: Path) -> None:
    """The first rig sensor's calibration films linked into the other sensors' folders."""
    first = dest / RIG_SENSORS[0]
    for name in RIG_SENSORS[1:]:
        for f in sorted(first.glob("calibration_*")):
            target = dest / name / f.name
            target.unlink(missing_ok=True)
            try:
                os.link(f, target)
            except OSError:  # another file system, or no hard links: a copy
                shutil.copy2(f, target)


def _render_space_run(args) -> dict:
    lr, dest, fps, artefacts, seed = args
    scenario = Scenario(lr.name, f"run {lr.name} of a sweep in space", pose_track(lr.run),
                        artefacts, fps)  # fmt: skip
    if lr.sensor:  # a rig's sensor: its own folder; the carrier's pose log is the run's
        dest = dest / lr.sensor
    else:
        write_csv(dest / f"{lr.name}.pose.csv", pose_columns(lr.poses), digits=10)
    if not _filmed(dest / f"{lr.name}.mp4", seed):
        render_scenario(scenario, Sensor(), dest / f"{lr.name}.mp4", seed)
    t = lr.poses[0]
    world = contact_in_world(lr)
    inside = np.asarray(lr.run.truth["in_contact"], float) == 1
    world[~inside] = np.nan
    write_csv(dest / f"{lr.name}.contact_truth.csv",
              {"t_s": lr.run.truth["t_s"], "px_mm": world[:, 0], "py_mm": world[:, 1],
               "pz_mm": world[:, 2], "phi_deg": lr.run.truth["phi_deg"],
               "slipping": lr.run.truth["slipping"]}, digits=10)  # fmt: skip
    return {"name": lr.name, **({"sensor": lr.sensor} if lr.sensor else {}),
            "height_mm": lr.height_mm, "offset_s": float(lr.run.offset_s),
            "frames": int(t.size)}  # fmt: skip


def _calibration_work(dest: Path, seed: int, fps: float, artefacts, rig: bool,
                      own: bool) -> list:  # fmt: skip
    """The calibration runs to film: eight pegs; in a rig, in the first sensor's folder, or
    in each sensor's (``own``)."""
    cal_seed = seed + CALIB_SEED_OFFSET
    folders = [(dest / n, cal_seed + RIG_CALIB_SEED_STEP * k) for k, n in enumerate(RIG_SENSORS)
               ] if rig else [(dest, cal_seed)]  # fmt: skip
    for folder, _ in folders:
        folder.mkdir(parents=True, exist_ok=True)
    work = []
    for folder, s in folders if own or not rig else folders[:1]:
        runs = simulate_runs("rigid", s, protocol=StageProtocol(fps=fps))
        work += [("calibration", run, folder, fps, artefacts, s + j) for j, run in enumerate(runs)]
    return work


def render_space_experiment(dest: str | Path, kind: str, seed: int, fps: float = EXPERIMENT_FPS,
                            crf: int = EXPERIMENT_CRF, jobs: int = 2, command: str = "",
                            rig: bool = False, own_calibration_films: bool = False
                            ) -> Path:  # fmt: skip
    """Simulate and film a sweep in space and its calibration into ``dest`` (with ``rig``,
    as a rig: module docstring); returns the path of ``object.json``."""
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    artefacts = replace(NOMINAL_ARTEFACTS, h264_crf=crf)
    cal = _calibration_work(dest, seed, fps, artefacts, rig, own_calibration_films)
    sweep, runs = simulate_space_sweep(kind, np.random.default_rng(seed), fps=fps, rig=rig)
    work = [(lr, dest, fps, artefacts, seed + 100 + k) for k, lr in enumerate(runs)]
    if rig:
        for lr in runs:
            if lr.height_mm == 0.0:  # one carrier log per run, shared by its sensors
                write_csv(dest / f"{lr.name}.pose.csv", pose_columns(carrier_poses(lr)),
                          digits=10)  # fmt: skip
        atomic_write_text(dest / RIG_NAME, rig_toml(f"made by {command or 'render'}"))
    if jobs > 1:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            list(pool.map(_render_calibration, cal))
            entries = list(pool.map(_render_space_run, work))
    else:
        [_render_calibration(c) for c in cal]
        entries = [_render_space_run(w) for w in work]
    if rig and not own_calibration_films:
        _link_calibration(dest)
    atomic_write_text(dest / "sensor.toml", dump_sensor(Sensor()))
    record = {"camwhisker": __version__, "command": command, "kind": kind, "seed": seed,
              "fps": fps, "object": truth_in_world(sweep), "runs": entries}  # fmt: skip
    atomic_write_text(dest / "object.json", dumps(record, indent=1) + "\n")
    return dest / "object.json"
