"""Planar stage runs lifted into space: walls and cylinders as exact 3-D objects.

The planar simulator's walls and cylinders (:mod:`camwhisker.sim.mechanics.objects`) are
exact 3-D objects when extruded across their plane: a wall is a plane, a cylinder one whose
axis is perpendicular to the plane of the sweep. Each run is swept at several heights
along that axis (:data:`HEIGHTS_MM`, each with its own noise), and its stage motion is
given as the base's pose (docs/sensor.md section 9) in a world frame turned and shifted
from the simulator's (:data:`WORLD_TURN_DEG`, :data:`WORLD_SHIFT_MM`).

The simulator's 3-D frame: its plane is x-z (x the stage's travel, z the whisker at
rest), the extrusion along y. A run's sensor frame S has x_S along the travel and z_S
along the shaft (its theta is 0 for a base travelling +x, the simulator's convention).
Spheres need the whisker bending out of its plane: they are not here.

As a rig (``rig=True``): the heights are three sensors on one carrier (:data:`RIG_SENSORS`,
low to high), the carrier's frame the sensor frame at height 0 and each sensor's mount its
height along y_S (:func:`rig_mounts`). A run moves the carrier once: its sensors share the
motion, the truth and the stage clock (their cameras start together), each with its own
front-end noise.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from camwhisker import __version__
from camwhisker.files.atomic import atomic_write_text
from camwhisker.files.jsonfile import dumps
from camwhisker.files.tables import write_csv
from camwhisker.io.rig import RIG_NAME, dump_rig
from camwhisker.sim.mechanics.experiment import (
    FRONT_END_NOISE,
    NoiseModel,
    StageProtocol,
    measure_signals,
    signal_arrays_from,
    simulate_run,
)
from camwhisker.sim.mechanics.objects import draw_sweep, turned_wall_run

__all__ = ["HEIGHTS_MM", "WORLD_TURN_DEG", "WORLD_SHIFT_MM", "RIG_SENSORS", "LiftedRun",
           "lifted_poses", "carrier_poses", "rig_mounts", "rig_toml", "simulate_space_sweep",
           "turned_wall_runs", "truth_in_world", "contact_in_world", "write_space_sweep",
           "pose_columns"]  # fmt: skip

#: Sweeps at these heights along the extrusion (mm): the axis is told by their spread.
HEIGHTS_MM = (-30.0, 0.0, 30.0)
#: The world frame: the simulator's turned by these Euler angles (zyx, deg) and shifted.
WORLD_TURN_DEG = (35.0, -20.0, 50.0)
WORLD_SHIFT_MM = (120.0, -40.0, 300.0)
#: The stage protocol of the percept sweeps (their travel covers a cylinder's far side).
MAX_TRAVEL_MM = 90.0
#: A rig's sensors, one per height of :data:`HEIGHTS_MM` (its folder's names).
RIG_SENSORS = ("low", "mid", "high")

_WORLD = Rotation.from_euler("zyx", WORLD_TURN_DEG, degrees=True)


def _sim_frame(angle_deg: float) -> np.ndarray:
    """Columns x_S, y_S, z_S in the simulator's 3-D frame of a run whose stage frame is
    turned by ``angle_deg`` in the plane."""
    a = math.radians(angle_deg)
    x_s = np.array([math.cos(a), 0.0, math.sin(a)])
    z_s = np.array([-math.sin(a), 0.0, math.cos(a)])
    return np.column_stack([x_s, np.cross(z_s, x_s), z_s])


def _to_world(p_sim: np.ndarray) -> np.ndarray:
    return _WORLD.apply(p_sim) + np.asarray(WORLD_SHIFT_MM)


def lifted_poses(stage: dict, pose: tuple, height_mm: float):
    """The base's poses in the world frame for a run's stage log: t_s (N,), position (N, 3)
    and quaternion (N, 4), scalar first."""
    x0, y0, angle = pose
    frame = _sim_frame(angle)
    x = np.asarray(stage["x_mm"], float)
    base = np.array([x0, height_mm, y0]) + np.outer(x, frame[:, 0])
    q = (_WORLD * Rotation.from_matrix(frame)).as_quat(scalar_first=True)
    return np.asarray(stage["t_s"], float), _to_world(base), np.tile(q, (x.size, 1))


def rig_mounts() -> dict[str, tuple]:
    """Each rig sensor's mount, X,Y,Z,QW,QX,QY,QZ: its height along the carrier's y axis."""
    return {n: (0.0, h, 0.0, 1.0, 0.0, 0.0, 0.0)
            for n, h in zip(RIG_SENSORS, HEIGHTS_MM, strict=True)}  # fmt: skip


def rig_toml(comment: str = "") -> str:
    """The simulated rig's file (:mod:`camwhisker.io.rig`), each sensor with the folder's
    sensor file and its own calibration runs."""
    return dump_rig([(n, m, None, None) for n, m in rig_mounts().items()], comment)


class LiftedRun:
    """One simulated run at one height: the run (signals, stage log, truth), its poses and
    its stage frame's pose in the simulator's plane (x0_mm, y0_mm, angle_deg); in a rig,
    also its sensor's name."""

    def __init__(self, run, height_mm: float, poses: tuple, pose: tuple, sensor: str = ""):
        self.run, self.height_mm, self.poses, self.pose = run, height_mm, poses, pose
        self.sensor = sensor

    @property
    def name(self) -> str:
        return self.run.name


def carrier_poses(lr: LiftedRun):
    """The rig carrier's poses over a run (the sensor frame at height 0): as
    :func:`lifted_poses`."""
    return lifted_poses(lr.run.stage, lr.pose, 0.0)


def pose_columns(poses: tuple) -> dict:
    """A pose log's columns from (t_s, position, quaternion)."""
    t, p, q = poses
    return {"t_s": t, "x_mm": p[:, 0], "y_mm": p[:, 1], "z_mm": p[:, 2], "qw": q[:, 0],
            "qx": q[:, 1], "qy": q[:, 2], "qz": q[:, 3]}  # fmt: skip


def _renoised(run, rng, noise: NoiseModel):
    """The run as another sensor of the rig sees it: the same motion and truth, its own
    front-end noise."""
    used = slice(0, run.info["n_steps"] + 1)
    x_cam = np.interp(run.signals["t_s"], run.schedule_t_s, run.schedule_x_mm)
    clean = signal_arrays_from(run.steps, used, x_cam)
    sig = measure_signals(clean["phi_deg"], clean["dz_mm"], run.info["theta_deg"], noise, rng)
    return replace(run, signals={"frame": run.signals["frame"], "t_s": run.signals["t_s"],
                                 **sig})  # fmt: skip


def _rig_runs(specs, rng, noise: NoiseModel, quiet=None, fps: float = StageProtocol.fps
              ) -> list[LiftedRun]:  # fmt: skip
    """Each run once, its carrier holding a sensor at every height."""
    protocol = StageProtocol(max_travel_mm=MAX_TRAVEL_MM, fps=fps)
    runs = []
    for i, spec in enumerate(specs):
        first = simulate_run(f"run{i}", "slide-box", spec.scene, rng, protocol=protocol,
                             noise=noise, travel_sign=spec.travel_sign)  # fmt: skip
        for name, h in zip(RIG_SENSORS, HEIGHTS_MM, strict=True):
            run = first if h == 0.0 else _renoised(first, rng, noise)
            if quiet is not None:
                run = replace(run, signals=quiet(run.signals, rng, noise))
            runs.append(LiftedRun(run, h, lifted_poses(run.stage, spec.pose, h), spec.pose,
                                  name))  # fmt: skip
    return runs


def _at_heights(specs, rng, noise: NoiseModel, first: int = 0, quiet=None,
                fps: float = StageProtocol.fps) -> list[LiftedRun]:  # fmt: skip
    protocol = StageProtocol(max_travel_mm=MAX_TRAVEL_MM, fps=fps)
    runs = []
    for h in HEIGHTS_MM:
        for i, spec in enumerate(specs, start=first):
            run = simulate_run(f"h{h:+.0f}run{i}", "slide-box", spec.scene, rng,
                               protocol=protocol, noise=noise, travel_sign=spec.travel_sign)
            if quiet is not None:
                run.signals = quiet(run.signals, rng, noise)
            runs.append(LiftedRun(run, h, lifted_poses(run.stage, spec.pose, h), spec.pose))
    return runs


def turned_wall_runs(sweep, turn_deg: float, rng, noise: NoiseModel = FRONT_END_NOISE
                     ) -> list[LiftedRun]:  # fmt: skip
    """A wall's first run again at every height, its travel and shaft turned by
    ``turn_deg`` about their plane's normal (x_S cross z_S; the planar simulator's stage
    frame turned by ``turn_deg``, :func:`~camwhisker.sim.mechanics.objects.turned_wall_run`)."""
    return _at_heights([turned_wall_run(sweep.runs[0], turn_deg)], rng, noise,
                       first=len(sweep.runs))  # fmt: skip


def simulate_space_sweep(kind: str, rng, noise: NoiseModel = FRONT_END_NOISE, quiet=None,
                         fps: float = StageProtocol.fps, rig: bool = False):  # fmt: skip
    """An object of ``kind`` ("wall", "cylinder" or "none") and its runs at every height.

    ``quiet(signals, rng, noise)``, where given for "none", replaces the signals by the
    front end's noise alone (nothing touched). With ``rig``, the heights are a rig's
    sensors (module docstring): a run per sensor per carrier run, ``sensor`` set.
    """
    sweep = draw_sweep(kind, rng)
    quiet = quiet if kind == "none" else None
    if rig:
        return sweep, _rig_runs(sweep.runs, rng, noise, quiet=quiet, fps=fps)
    return sweep, _at_heights(sweep.runs, rng, noise, quiet=quiet, fps=fps)


def contact_in_world(lr: LiftedRun) -> np.ndarray:
    """The run's true contact points (camera frames, shape (N, 3)) in the world frame."""
    x0, y0, angle = lr.pose
    frame = _sim_frame(angle)
    cx = np.asarray(lr.run.truth["contact_x_mm"], float)
    cy = np.asarray(lr.run.truth["contact_y_mm"], float)
    base = np.array([x0, lr.height_mm, y0])
    return _to_world(base + np.outer(cx, frame[:, 0]) + np.outer(cy, frame[:, 2]))


def truth_in_world(sweep) -> dict:
    """The true object in the world frame: ``model`` and section 9's parameters."""
    t = sweep.truth
    if sweep.kind == "cylinder":
        c = _to_world(np.array([t["center_x_mm"], 0.0, t["center_y_mm"]]))
        u = _WORLD.apply([0.0, 1.0, 0.0])
        u = u if u[np.argmax(np.abs(u))] > 0 else -u
        return {"model": "cylinder", "center_x_mm": c[0], "center_y_mm": c[1],
                "center_z_mm": c[2], "axis_x": u[0], "axis_y": u[1], "axis_z": u[2],
                "radius_mm": t["radius_mm"]}
    if sweep.kind == "wall":
        a = math.radians(t["angle_deg"])
        n = _WORLD.apply([-math.sin(a), 0.0, math.cos(a)])  # toward the side the base comes from
        point = _to_world(np.array([t["end_x_mm"], 0.0, t["end_y_mm"]]))
        return {"model": "plane", "normal_x": n[0], "normal_y": n[1], "normal_z": n[2],
                "distance_mm": float(n @ point)}
    return {"model": "none"}


def write_space_sweep(dest: str | Path, kind: str, seed: int, command: str = "",
                      noise: NoiseModel = FRONT_END_NOISE, rig: bool = False
                      ) -> list[Path]:  # fmt: skip
    """Simulate a sweep and write, per run, ``NAME.signals.csv`` and ``NAME.pose.csv`` (on the
    stage's clock), and ``object.json``: the object in the world frame, the runs' true clock
    offsets, how it was made. With ``rig``: ``rig.toml``, per run the carrier's
    ``RUN.pose.csv`` and per sensor ``SENSOR/RUN.signals.csv``. Returns the paths written."""
    out = Path(dest)
    out.mkdir(parents=True, exist_ok=True)
    sweep, runs = simulate_space_sweep(kind, np.random.default_rng(seed), noise, rig=rig)
    paths = []
    for lr in runs:
        sig = lr.run.signals
        signals = {k: sig[k] for k in ("frame", "t_s", "dz_mm", "phi_deg", "theta_deg", "ok")}
        table = out / lr.sensor / f"{lr.name}.signals.csv"
        write_csv(table, signals, digits=8)
        paths.append(table)
        if not rig or lr.height_mm == 0.0:  # a rig's runs share the carrier's log
            write_csv(out / f"{lr.name}.pose.csv",
                      pose_columns(carrier_poses(lr) if rig else lr.poses), digits=9)
            paths.append(out / f"{lr.name}.pose.csv")
    record = {"camwhisker": __version__, "command": command, "kind": kind, "seed": seed,
              "object": truth_in_world(sweep),
              "runs": [{"name": lr.name, **({"sensor": lr.sensor} if rig else {}),
                        "height_mm": lr.height_mm, "offset_s": lr.run.offset_s}
                       for lr in runs]}  # fmt: skip
    if rig:
        atomic_write_text(out / RIG_NAME, rig_toml(f"made by {command or 'simulate-space'}"))
        paths.append(out / RIG_NAME)
    atomic_write_text(out / "object.json", dumps(record, indent=1) + "\n")
    return [*paths, out / "object.json"]
