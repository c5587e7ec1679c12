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
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

from camwhisker import __version__
from camwhisker.files.atomic import atomic_write_text
from camwhisker.files.jsonfile import dumps
from camwhisker.files.tables import write_csv
from camwhisker.sensor.file import Sensor, dump_sensor
from camwhisker.sim.mechanics import StageProtocol, simulate_runs
from camwhisker.sim.mechanics.space import contact_in_world, simulate_space_sweep, truth_in_world
from camwhisker.sim.render.experiment import EXPERIMENT_CRF, EXPERIMENT_FPS, pose_track, render_run
from camwhisker.sim.render.scenarios import NOMINAL_ARTEFACTS, Scenario
from camwhisker.sim.render.video import render_scenario

__all__ = ["render_space_experiment", "CALIB_SEED_OFFSET"]

#: The calibration runs' simulation seed, from the experiment's.
CALIB_SEED_OFFSET = 500


def _render_space_run(args) -> dict:
    lr, dest, fps, artefacts, seed = args
    scenario = Scenario(lr.name, f"run {lr.name} of a sweep in space", pose_track(lr.run),
                        artefacts, fps)  # fmt: skip
    render_scenario(scenario, Sensor(), dest / f"{lr.name}.mp4", seed)
    t, p, q = lr.poses
    write_csv(dest / f"{lr.name}.pose.csv",
              {"t_s": t, "x_mm": p[:, 0], "y_mm": p[:, 1], "z_mm": p[:, 2], "qw": q[:, 0],
               "qx": q[:, 1], "qy": q[:, 2], "qz": q[:, 3]}, digits=10)  # fmt: skip
    world = contact_in_world(lr)
    inside = np.asarray(lr.run.truth["in_contact"], float) == 1
    world[~inside] = np.nan
    write_csv(dest / f"{lr.name}.contact_truth.csv",
              {"t_s": lr.run.truth["t_s"], "px_mm": world[:, 0], "py_mm": world[:, 1],
               "pz_mm": world[:, 2], "phi_deg": lr.run.truth["phi_deg"],
               "slipping": lr.run.truth["slipping"]}, digits=10)  # fmt: skip
    return {"name": lr.name, "height_mm": lr.height_mm, "offset_s": float(lr.run.offset_s),
            "frames": int(t.size)}


def render_space_experiment(dest: str | Path, kind: str, seed: int, fps: float = EXPERIMENT_FPS,
                            crf: int = EXPERIMENT_CRF, jobs: int = 2, command: str = "") -> Path:
    """Simulate and film a sweep in space and its calibration into ``dest``; returns the
    path of ``object.json``."""
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    artefacts = replace(NOMINAL_ARTEFACTS, h264_crf=crf)
    cal_seed = seed + CALIB_SEED_OFFSET
    cal = [("calibration", run, dest, fps, artefacts, cal_seed + j)
           for j, run in enumerate(simulate_runs("rigid", cal_seed,
                                                 protocol=StageProtocol(fps=fps)))]  # fmt: skip
    sweep, runs = simulate_space_sweep(kind, np.random.default_rng(seed), fps=fps)
    work = [(lr, dest, fps, artefacts, seed + 100 + k) for k, lr in enumerate(runs)]
    if jobs > 1:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            list(pool.map(render_run, cal))
            entries = list(pool.map(_render_space_run, work))
    else:
        [render_run(c) for c in cal]
        entries = [_render_space_run(w) for w in work]
    atomic_write_text(dest / "sensor.toml", dump_sensor(Sensor()))
    record = {"camwhisker": __version__, "command": command, "kind": kind, "seed": seed,
              "fps": fps, "object": truth_in_world(sweep), "runs": entries}  # fmt: skip
    atomic_write_text(dest / "object.json", dumps(record, indent=1) + "\n")
    return dest / "object.json"
