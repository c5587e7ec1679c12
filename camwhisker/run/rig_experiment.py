"""A rig's experiment: several sensors on one carrier give one map and one object.

An experiment folder with a rig file (``rig.toml``, :mod:`camwhisker.io.rig`) holds::

    FOLDER/
      rig.toml                 the sensors, each with its mount on the carrier
      sensor.toml              the sensor file of every sensor the rig gives none
      RUN.pose.csv             per run: the carrier's pose log (docs/sensor.md section 9)
      SENSOR/                  per sensor of the rig, named as in it:
        RUN.mp4                  its video of each run (RUN as the carrier's log)
        calibration_*.mp4        its calibration runs, each with its stage log
        calibration_*.stage.csv  (an r_mm column); none where the rig gives a calibration

A sensor's folder may also hold stage runs (``NAME.mp4`` with ``NAME.stage.csv``), as a
one-sensor folder does. Each sensor is batched with its own sensor file, calibrated from
its own calibration runs (or the rig's file), and its runs' contacts placed in W by the
carrier's pose composed with its mount; the runs in space of every sensor together give
one object (``percept/space.json``) and one map (``map.*``). Written under the output
folder: per sensor ``SENSOR/`` (``signals/``, ``calib.toml``, ``contact/``, ``percept/``,
the Fig. 7A plot), and ``summary.json`` naming each sensor, its mount and calibration.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

from camwhisker import __version__
from camwhisker.contact.calibrate import read_calibration, write_calibration
from camwhisker.contact.stage import read_stage_log
from camwhisker.files import jsonfile
from camwhisker.files.atomic import atomic_write_text
from camwhisker.io.poses import read_pose_log
from camwhisker.io.rig import Rig, RigSensor, read_rig
from camwhisker.io.signals import read_signal_table
from camwhisker.run.experiment import (
    POSE_SUFFIX,
    STAGE_SUFFIX,
    VIDEO_SUFFIXES,
    ExperimentError,
    Recording,
    batch_runs,
    calibrate_runs,
    calibration_record,
    contact_step,
    find_videos,
    folder_sensor,
    has_r_mm,
    planar_percepts,
    run_entries,
    space_percept,
)
from camwhisker.sensor.file import Sensor, load_sensor

__all__ = ["find_rig_recordings", "run_rig_experiment"]


@dataclass
class _Done:
    """One sensor's steps: its runs, tables, signals, calibration and contacts."""

    sensor: RigSensor
    source: str
    runs: list
    signals: dict
    calib: object
    calibrated: str
    contacts: dict
    failed: dict
    percepts: dict
    batch: dict


def _no_loose_files(folder: Path, rig: Rig) -> None:
    """A rig's videos and stage logs are in its sensors' folders, not beside rig.toml."""
    loose = [p for s in (*VIDEO_SUFFIXES, STAGE_SUFFIX) for p in sorted(folder.glob(f"*{s}"))]
    if loose:
        raise ExperimentError(f"{loose[0]}: a rig's videos and stage logs go in its sensors' "
                              f"folders (SENSOR/{loose[0].name}, SENSOR as named in "
                              f"{rig.path})")  # fmt: skip
    for sub in sorted(p for p in folder.iterdir() if p.is_dir()):
        if sub.name not in rig.names and find_videos(sub):
            raise ExperimentError(f"{sub}: recordings of a sensor {sub.name} that {rig.path} "
                                  f"does not name (it names {', '.join(rig.names)})")  # fmt: skip


def _sensor_runs(folder: Path, s: RigSensor, rig: Rig, carrier: dict) -> list[Recording]:
    """One sensor's runs: its videos with its stage logs or the carrier's pose logs."""
    sub = folder / s.name
    videos = find_videos(sub) if sub.is_dir() else {}
    if not videos:
        raise ExperimentError(f"{rig.path}: sensor {s.name} has no recordings (expected its "
                              f"videos in {sub}/)")  # fmt: skip
    own_poses = sorted(sub.glob(f"*{POSE_SUFFIX}"))
    if own_poses:
        raise ExperimentError(f"{own_poses[0]}: a rig's pose logs are the carrier's, one per "
                              f"run beside {rig.path.name}: {folder}/RUN{POSE_SUFFIX}")
    stages = {p.name[: -len(STAGE_SUFFIX)]: p for p in sorted(sub.glob(f"*{STAGE_SUFFIX}"))}
    for name, log in stages.items():
        if name not in videos:
            raise ExperimentError(f"{log}: no video {name}.mp4 or {name}.avi beside it")
    runs = []
    for name, video in sorted(videos.items()):
        if name in stages and name in carrier:
            raise ExperimentError(f"{video}: run {name} has a stage log {stages[name]} and a "
                                  f"carrier pose log {carrier[name]}; keep the one its base "
                                  "followed")  # fmt: skip
        if name not in stages and name not in carrier:
            raise ExperimentError(f"{video}: no stage log {name}{STAGE_SUFFIX} beside it and "
                                  f"no carrier pose log {folder / (name + POSE_SUFFIX)}")
        log = stages.get(name) or carrier[name]
        runs.append(Recording(name, video, log, name in stages and has_r_mm(log)))
    if s.calibration is None and not any(r.calibration for r in runs):
        raise ExperimentError(f"{sub}: sensor {s.name} has no calibration run (a stage log "
                              "with an r_mm column) and the rig gives it no calibration "
                              "file")  # fmt: skip
    return runs


def find_rig_recordings(folder: str | Path, rig: Rig) -> dict[str, list[Recording]]:
    """Each sensor's runs, by the rig's sensor names (module docstring for the layout).

    Raises
    ------
    ExperimentError
        No such folder; videos or stage logs outside the sensors' folders; a folder of
        recordings of a sensor the rig does not name; a sensor of the rig without
        recordings or (without a calibration file) without a calibration run; a video
        without its log or a log without its video; a carrier pose log no sensor filmed.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ExperimentError(f"{folder}: no such folder")
    _no_loose_files(folder, rig)
    carrier = {p.name[: -len(POSE_SUFFIX)]: p for p in sorted(folder.glob(f"*{POSE_SUFFIX}"))}
    found = {s.name: _sensor_runs(folder, s, rig, carrier) for s in rig.sensors}
    filmed = {r.name for runs in found.values() for r in runs}
    for name, log in carrier.items():
        if name not in filmed:
            raise ExperimentError(f"{log}: no sensor of {rig.path} has a video {name}.mp4 "
                                  "in its folder")  # fmt: skip
    return found


def _sensor_of(folder: Path, s: RigSensor, sensor, cache: dict) -> Sensor:
    key = str(s.sensor_file) if s.sensor_file else None
    if key not in cache:
        cache[key] = load_sensor(s.sensor_file) if s.sensor_file else folder_sensor(folder, sensor)
    return cache[key]


def _one_sensor(folder: Path, out: Path, s: RigSensor, runs: list[Recording], sensor: Sensor,
                opts: dict) -> _Done:  # fmt: skip
    """Steps 1-3 and the planar percepts for one sensor of the rig, under ``out/SENSOR``."""
    mine = out / s.name
    tables, batch = batch_runs(runs, sensor, mine, opts["jobs"], opts["progress"])
    signals = {r.name: read_signal_table(tables[r.name]) for r in runs}
    logs = {r.name: read_pose_log(r.stage, s.mount) if r.in_space else read_stage_log(r.stage)
            for r in runs}  # fmt: skip
    if s.calibration is not None:
        calib, calibrated = read_calibration(s.calibration), str(s.calibration)
    else:
        calib, cal_data = calibrate_runs(runs, sensor, tables, signals, logs,
                                         f"{opts['command']} (sensor {s.name})")  # fmt: skip
        calibrated = str(mine / "calib.toml")
        write_calibration(mine / "calib.toml", calib)
        if opts["plots"]:
            from camwhisker.contact.plots import plot_gm_model

            plot_gm_model(calib, cal_data, mine / "fig7a_gm_model.png",
                          f"Fig. 7A: sensor {s.name}")  # fmt: skip
    contacts, failed = {}, {}
    for r in runs:
        try:
            contacts[r.name] = contact_step(r, signals[r.name], logs[r.name], calib,
                                            opts["per"], mine)  # fmt: skip
        except ValueError as exc:  # one run's contact fails alone; the others go on
            failed[r.name] = str(exc)
    planar = [r for r in runs if r.name in contacts and not r.calibration and not r.in_space]
    percepts = planar_percepts(mine, planar, opts["plots"])
    return _Done(s, sensor.source, runs, signals, calib, calibrated, contacts, failed,
                 percepts, batch)  # fmt: skip


def _batch_timing(done: list[_Done]) -> dict:
    """The sensors' batch timings added up (speed: all frames over all the work)."""
    frames = sum(d.batch["frames"] for d in done)
    work = sum(d.batch["frames"] / d.batch["frames_per_s_per_core"] for d in done
               if d.batch["frames"] and d.batch["frames_per_s_per_core"] > 0)  # fmt: skip
    return {"seconds": sum(d.batch["seconds"] for d in done), "frames": frames,
            "reused": sum(d.batch["reused"] for d in done),
            "frames_per_s_per_core": frames / work if work else math.nan}  # fmt: skip


def run_rig_experiment(folder: str | Path, out: str | Path, rig: str | Path, *,
                       sensor: str | Path | Sensor | None = None, jobs: int = 2,
                       per: str = "pause", progress: bool = True, command: str = "",
                       plots: bool = True) -> dict:  # fmt: skip
    """:func:`~camwhisker.run.experiment.run_experiment` for a rig's folder (module docstring).

    ``sensor`` is the sensor file of the sensors the rig gives none (default: the
    folder's ``sensor.toml``). Returns the summary, also in ``out/summary.json``:
    ``rig`` (each sensor's name, mount, sensor file, calibration), ``runs`` (each with
    its ``sensor``), ``space``, ``failed`` (by ``SENSOR/RUN``), ``timings``, ``provenance``.
    """
    folder, out = Path(folder), Path(out)
    rig = read_rig(rig)
    found = find_rig_recordings(folder, rig)
    opts = {"jobs": jobs, "progress": progress, "per": per, "plots": plots,
            "command": command or f"camwhisker experiment {folder}"}  # fmt: skip
    t0, cache, done = time.perf_counter(), {}, []
    for s in rig.sensors:
        done.append(_one_sensor(folder, out, s, found[s.name],
                                _sensor_of(folder, s, sensor, cache), opts))  # fmt: skip
    steps_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    tables = {f"{d.sensor.name}/{r.name}": out / d.sensor.name / "contact" / f"{r.name}.csv"
              for d in done for r in d.runs if r.in_space and r.name in d.contacts}  # fmt: skip
    space = {"space": space_percept(out, tables, plots, command)} if tables else {}
    timings = {"batch": _batch_timing(done)}
    timings["calibrate_and_contact"] = {"seconds": steps_s - timings["batch"]["seconds"]}
    timings["percept"] = {"seconds": time.perf_counter() - t0}
    summary = {
        "rig": {"file": str(rig.path), "sensors": [_sensor_record(d) for d in done]},
        "runs": [{"sensor": d.sensor.name, **e} for d in done
                 for e in run_entries(d.runs, d.signals, d.contacts, d.percepts)],
        **space,
        "failed": {f"{d.sensor.name}/{n}": why for d in done for n, why in d.failed.items()},
        "timings": timings,
        "provenance": {"camwhisker_version": __version__, "command": command,
                       "folder": str(folder), "rig": str(rig.path), "per": per},
    }  # fmt: skip
    atomic_write_text(out / "summary.json", jsonfile.dumps(summary, indent=2) + "\n")
    return summary


def _sensor_record(d: _Done) -> dict:
    n_cal = 0 if d.sensor.calibration is not None else sum(r.calibration for r in d.runs)
    return {"name": d.sensor.name, "mount": d.sensor.mount_record(), "sensor": d.source,
            "calibration": {"file": d.calibrated, "given": d.sensor.calibration is not None,
                            **calibration_record(d.calib, n_cal)}}  # fmt: skip
