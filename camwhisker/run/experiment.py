"""The user's own pipeline: a folder of recordings -> signals, calibration, contacts, objects.

A folder holds, per run, ``NAME.mp4`` or ``NAME.avi`` with ``NAME.stage.csv`` (its stage
log, docs/sensor.md section 7) or ``NAME.pose.csv`` (the base's pose log, section 9: a
base moving in space), and one sensor file ``sensor.toml`` (or give ``sensor``). The
calibration runs are those whose stage log has an ``r_mm`` column. :func:`run_experiment`
runs, in order:

1. ``batch``: the front end on every video (parallel processes; finished tables reused);
2. ``calibrate``: GM (eq. 8), sigma_GM and the MF table from the calibration runs;
3. ``contact``: a contact table per run (docs/sensor.md section 7; with the contact point
   in space for runs with a pose log, section 9);
4. ``percept``: the object behind each other stage run's contacts, and the plots (Fig.
   7A; the contacts with the fitted object per run); the runs in space together give one
   object in the world frame (``percept/space.json``) and one map (``map.*``).

Everything lands under the output folder with ``summary.json`` saying how it was made.
No truth is read: :mod:`camwhisker.bench.chain` adds the check against a simulator's.
A folder with a rig file (``rig.toml``: several sensors on one carrier) is a rig's:
:mod:`camwhisker.run.rig_experiment`.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camwhisker import __version__
from camwhisker.contact.calibrate import CalibrationRun, calibrate, write_calibration
from camwhisker.contact.pipeline import Calibration, RunAnalysis, contact_rows
from camwhisker.contact.space import contact_rows_in_space
from camwhisker.contact.stage import read_stage_log
from camwhisker.files import jsonfile
from camwhisker.files.atomic import atomic_write_text
from camwhisker.files.tables import write_csv
from camwhisker.io.poses import Mount, read_pose_log
from camwhisker.io.rig import RIG_NAME
from camwhisker.io.signals import read_signal_table, sidecar_path
from camwhisker.run.campaign import BatchTask, run_many
from camwhisker.sensor.file import Sensor, load_sensor
from camwhisker.vision.tracker import FrontEndOptions

__all__ = ["ExperimentError", "Recording", "find_recordings", "find_videos", "run_experiment",
           "format_experiment", "VIDEO_SUFFIXES", "SENSOR_NAME"]  # fmt: skip

#: A run's video, by suffix, in the order looked for.
VIDEO_SUFFIXES = (".mp4", ".avi")
STAGE_SUFFIX = ".stage.csv"
POSE_SUFFIX = ".pose.csv"
#: The folder's sensor file, where none is given.
SENSOR_NAME = "sensor.toml"


class ExperimentError(ValueError):
    """A folder that cannot be run; the message names the file or run."""


@dataclass(frozen=True)
class Recording:
    """One run of a folder: its video, its stage log or pose log, whether it calibrates."""

    name: str
    video: Path
    stage: Path
    calibration: bool

    @property
    def in_space(self) -> bool:
        return self.stage.name.endswith(POSE_SUFFIX)


def has_r_mm(stage: Path) -> bool:
    """Whether a stage log has an r_mm column: a calibration run's."""
    with open(stage, encoding="utf-8") as fh:
        header = fh.readline()
    return "r_mm" in (c.strip() for c in header.split(","))


def find_recordings(folder: str | Path) -> list[Recording]:
    """The runs of ``folder``, sorted by name.

    Raises
    ------
    ExperimentError
        No such folder, a video without its stage log, a stage log without its video, a
        run with two videos, no run at all, or no calibration run.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ExperimentError(f"{folder}: no such folder")
    videos = find_videos(folder)
    logs = _logs(folder)
    for name, video in videos.items():
        if name not in logs:
            raise ExperimentError(f"{video}: no stage log {name}{STAGE_SUFFIX} or pose log "
                                  f"{name}{POSE_SUFFIX} beside it")  # fmt: skip
    for name, log in logs.items():
        if name not in videos:
            raise ExperimentError(f"{log}: no video {name}.mp4 or {name}.avi beside it")
    if not videos:
        raise ExperimentError(f"{folder}: no run (NAME.mp4 or NAME.avi with "
                              f"NAME{STAGE_SUFFIX} or NAME{POSE_SUFFIX})")  # fmt: skip
    runs = [Recording(n, videos[n], logs[n], not logs[n].name.endswith(POSE_SUFFIX)
                      and has_r_mm(logs[n])) for n in sorted(videos)]  # fmt: skip
    if not any(r.calibration for r in runs):
        raise ExperimentError(f"{folder}: no calibration run (a stage log with an r_mm "
                              "column, docs/sensor.md section 7)")  # fmt: skip
    return runs


def find_videos(folder: Path) -> dict[str, Path]:
    """The videos of ``folder`` by run name; a run with two videos is an error."""
    videos: dict[str, Path] = {}
    for suffix in VIDEO_SUFFIXES:
        for video in sorted(folder.glob(f"*{suffix}")):
            if video.stem in videos:
                raise ExperimentError(f"{video}: run {video.stem} has two videos "
                                      f"({videos[video.stem].name} too)")  # fmt: skip
            videos[video.stem] = video
    return videos


def _logs(folder: Path) -> dict[str, Path]:
    """Each run's log by name: a stage log or a pose log, not both."""
    logs: dict[str, Path] = {}
    for suffix in (STAGE_SUFFIX, POSE_SUFFIX):
        for p in sorted(folder.glob(f"*{suffix}")):
            name = p.name[: -len(suffix)]
            if name in logs:
                raise ExperimentError(f"{p}: run {name} has a stage log and a pose log; "
                                      "keep the one its base followed")  # fmt: skip
            logs[name] = p
    return logs


def folder_sensor(folder: Path, sensor: str | Path | Sensor | None) -> Sensor:
    """The sensor given, or the folder's sensor file."""
    if isinstance(sensor, Sensor):
        return sensor
    if sensor is None:
        sensor = folder / SENSOR_NAME
        if not sensor.is_file():
            raise ExperimentError(f"{folder}: no {SENSOR_NAME} (or give the sensor file)")
    return load_sensor(sensor)


def run_experiment(folder: str | Path, out: str | Path, *, sensor: str | Path | Sensor | None
                   = None, jobs: int = 2, per: str = "pause", progress: bool = True,
                   command: str = "", plots: bool = True, mount: Mount | None = None,
                   rig: str | Path | None = None) -> dict:  # fmt: skip
    """Batch, calibrate, contact and percepts over a folder of recordings.

    Parameters
    ----------
    folder : path
        The recordings (module docstring).
    out : path
        Written: ``signals/NAME.csv`` (with sidecars), ``calib.toml`` and ``calib.mf.csv``,
        ``contact/NAME.csv``, ``percept/NAME.json``, the figures and ``summary.json``.
    sensor : path or Sensor, optional
        Default: the folder's ``sensor.toml``.
    jobs : int
        Videos processed in parallel.
    per : {"pause", "frame"}
        Contact from the medians of each stage pause (the paper's) or from every frame.
    command : str
        How it was called, for the summary and the calibration's provenance.
    mount : Mount, optional
        Where the pose logs give a carrier's pose: the sensor's pose in the carrier's frame.
    rig : path, optional
        A rig file (:mod:`camwhisker.io.rig`); default: the folder's ``rig.toml`` where it
        has one. With a rig, the folder is a rig's (:mod:`camwhisker.run.rig_experiment`).

    Returns
    -------
    dict
        The summary, also in ``out/summary.json`` (strict JSON); ``failed`` names the runs
        whose contact could not be made and why (the other runs are done).
    """
    folder, out = Path(folder), Path(out)
    if rig is not None or (folder / RIG_NAME).is_file():
        from camwhisker.run.rig_experiment import run_rig_experiment

        if mount is not None:
            raise ExperimentError(f"{rig or folder / RIG_NAME}: the rig file gives each "
                                  "sensor's mount; leave out --mount")  # fmt: skip
        return run_rig_experiment(folder, out, rig or folder / RIG_NAME, sensor=sensor,
                                  jobs=jobs, per=per, progress=progress, command=command,
                                  plots=plots)  # fmt: skip
    runs = find_recordings(folder)
    sensor = folder_sensor(folder, sensor)
    timings: dict = {}
    tables, timings["batch"] = batch_runs(runs, sensor, out, jobs, progress)
    signals = {r.name: read_signal_table(tables[r.name]) for r in runs}
    logs = {r.name: read_pose_log(r.stage, mount) if r.in_space else read_stage_log(r.stage)
            for r in runs}  # fmt: skip

    t0 = time.perf_counter()
    calib, cal_data = calibrate_runs(runs, sensor, tables, signals, logs,
                                     command or f"camwhisker experiment {folder}")  # fmt: skip
    write_calibration(out / "calib.toml", calib)
    timings["calibrate"] = {"seconds": time.perf_counter() - t0}

    t0 = time.perf_counter()
    contacts, failed = {}, {}
    for r in runs:
        try:
            contacts[r.name] = contact_step(r, signals[r.name], logs[r.name], calib, per, out)
        except ValueError as exc:  # one run's contact fails alone; the others go on
            failed[r.name] = str(exc)
    timings["contact"] = {"seconds": time.perf_counter() - t0}

    t0 = time.perf_counter()
    done = [r for r in runs if r.name in contacts]
    percepts = planar_percepts(out, [r for r in done if not r.calibration and not r.in_space],
                               plots)  # fmt: skip
    in_space = [r for r in done if r.in_space]
    if in_space:
        percepts["space"] = space_percept(out, {r.name: out / "contact" / f"{r.name}.csv"
                                                for r in in_space}, plots, command)  # fmt: skip
    if plots:
        from camwhisker.contact.plots import plot_gm_model

        plot_gm_model(calib, cal_data, out / "fig7a_gm_model.png",
                      f"Fig. 7A: {command or 'camwhisker experiment'}")  # fmt: skip
    timings["percept"] = {"seconds": time.perf_counter() - t0}
    summary = _summary(runs, signals, contacts, percepts, calib, timings)
    summary["failed"] = failed
    summary["provenance"] = {"camwhisker_version": __version__, "command": command,
                             "folder": str(folder), "sensor": sensor.source,
                             "calibration": str(out / "calib.toml"), "per": per}  # fmt: skip
    atomic_write_text(out / "summary.json", jsonfile.dumps(summary, indent=2) + "\n")
    return summary


def contact_step(r: Recording, signals: dict, log, calib: Calibration, per: str,
                 out: Path) -> tuple[dict, RunAnalysis]:  # fmt: skip
    """Step 3: one run's contact table, written; a run in space gets its points in W."""
    if r.in_space:
        cols, run, _ = contact_rows_in_space(signals, log, calib, mode=per)
    else:
        cols, run = contact_rows(signals, log, calib, mode=per)
    write_csv(out / "contact" / f"{r.name}.csv", cols)
    return cols, run


def space_percept(out: Path, runs: dict[str, Path], plots: bool, command: str) -> dict:
    """Step 4 in space: one object from every run in space (contact tables by run), and
    their map's points."""
    from camwhisker.percept.contact_map import plot_contact_map, read_contact_points, write_ply
    from camwhisker.percept.solids import perceive_solid, read_surfels3, solid_record

    tables = list(runs.values())
    surfels = read_surfels3(tables)
    p = perceive_solid(surfels)
    record = {"camwhisker": __version__, "contacts": [str(t) for t in tables],
              **solid_record(p, surfels)}  # fmt: skip
    atomic_write_text(out / "percept" / "space.json", jsonfile.dumps(record, indent=1) + "\n")
    points = read_contact_points(tables)
    write_ply(out / "map.ply", points, comments=[command or "camwhisker experiment"])
    if plots:
        from camwhisker.percept.contact_map import read_percept

        plot_contact_map(points, out / "map.png", command or "camwhisker experiment",
                         read_percept(out / "percept" / "space.json"))  # fmt: skip
    return {"object": p.best.model, "model": p.best.model, "contacts": p.n_surfels,
            "params": p.best.params, "intervals_95": p.best.intervals,
            "runs": list(runs)}  # fmt: skip


def batch_runs(runs: list, sensor: Sensor, out: Path, jobs: int, progress: bool
              ) -> tuple[dict, dict]:  # fmt: skip
    """Step 1: batch on every run's video; its tables by name and the step's timing.

    ``runs`` need ``name`` and ``video``. Tables already complete are reused.
    """
    t0 = time.perf_counter()
    tables = {r.name: out / "signals" / f"{r.name}.csv" for r in runs}
    batch = run_many([(r.video, tables[r.name]) for r in runs],
                     BatchTask(sensor, FrontEndOptions()), jobs=jobs, progress=progress)
    if batch.interrupted:
        raise KeyboardInterrupt
    if batch.failed:
        raise ExperimentError("batch failed:\n" + "\n".join(f"  {f.video}: {f.reason}"
                                                           for f in batch.failed))  # fmt: skip
    # Per-core speed from each table's own timing (also for tables reused from a previous run).
    frames = work_s = 0.0
    for path in tables.values():
        timing = json.loads(sidecar_path(path).read_text())
        frames += timing["frames_decoded"]
        work_s += timing["timings"]["seconds"]
    return tables, {"seconds": time.perf_counter() - t0, "frames": int(frames),
                    "reused": batch.count("skipped"),
                    "frames_per_s_per_core": frames / work_s if work_s else math.nan}  # fmt: skip


def calibrate_runs(runs: list, sensor: Sensor, tables: dict, signals: dict, logs: dict,
                   command: str) -> tuple[Calibration, dict]:  # fmt: skip
    """Step 2: the contact calibration from the runs that calibrate; it and its data."""
    cal = [r for r in runs if r.calibration]
    if not cal:
        raise ExperimentError("no calibration run")
    calib, _, cal_data = calibrate(
        [CalibrationRun(signals[r.name], logs[r.name], str(tables[r.name])) for r in cal],
        sensor.whisker.length_mm, sensor.source, command)
    return calib, cal_data


def planar_percepts(out: Path, runs: list[Recording], plots: bool) -> dict:
    """Step 4: each object run's percept (JSON, and its picture)."""
    from camwhisker.percept.percepts import object_of, outline, perceive, percept_record
    from camwhisker.percept.surfels import read_surfels

    found = {}
    for r in runs:
        table = out / "contact" / f"{r.name}.csv"
        surfels = read_surfels([table])
        if surfels.n == 0:
            found[r.name] = {"object": "no contact", "contacts": 0}
            continue
        p = perceive(surfels)
        record = {"camwhisker": __version__, "contacts": str(table), **percept_record(p)}
        atomic_write_text(out / "percept" / f"{r.name}.json", jsonfile.dumps(record, indent=1)
                          + "\n")  # fmt: skip
        found[r.name] = {"object": object_of(p), "model": p.best.model, "contacts": surfels.n,
                         "params": p.best.params, "intervals_95": p.best.intervals}  # fmt: skip
        if plots:
            from camwhisker.contact.plots import plot_percept

            plot_percept(surfels.xy_mm, surfels.dir, surfels.free_xy_mm,
                         outline(p.best, surfels.xy_mm), f"{r.name}: {object_of(p)}",
                         out / "percept" / f"{r.name}.png", "camwhisker experiment")  # fmt: skip
    return found


def _summary(runs, signals, contacts, percepts, calib: Calibration, timings) -> dict:
    space = {"space": percepts["space"]} if "space" in percepts else {}
    return {"runs": run_entries(runs, signals, contacts, percepts), **space,
            "calibration": calibration_record(calib, sum(r.calibration for r in runs)),
            "timings": timings}  # fmt: skip


def calibration_record(calib: Calibration, n_runs: int) -> dict:
    """The summary's calibration: GM's model, parameters and intervals, the runs it used."""
    return {"gm_model": calib.gm.kind, "gm_params": calib.gm.params, "gm_ci95": calib.gm.ci,
            "calibration_runs": n_runs}  # fmt: skip


def run_entries(runs, signals, contacts, percepts) -> list[dict]:
    """The summary's line per run whose contact was made."""
    per_run = []
    for r in runs:
        if r.name not in contacts:
            continue
        cols, run = contacts[r.name]
        per_run.append({
            "name": r.name, "role": "calibration" if r.calibration else "object",
            "frames": int(signals[r.name]["ok"].size), "ok": int(signals[r.name]["ok"].sum()),
            "log": "pose" if r.in_space else "stage",
            "offset_s": run.offset_s, "x_contact_mm": run.x_contact_mm,
            "rows_with_estimate": int(np.isfinite(cols["r_hat_mm"]).sum()),
            **({"percept": percepts[r.name]} if r.name in percepts else {}),
        })  # fmt: skip
    return per_run


def _calibration_line(c: dict, who: str = "calibration") -> str:
    params = ", ".join(f"{k} {v:.4g}" for k, v in c["gm_params"].items())
    where = f"{c['file']}" if c.get("given") else f"{c['calibration_runs']} runs"
    return f"{who}: {where}; GM model {c['gm_model']} ({params})"


def _rig_lines(rig: dict) -> list[str]:
    lines = [f"rig {rig['file']}: {len(rig['sensors'])} sensors"]
    for sn in rig["sensors"]:
        m = sn["mount"]
        pos = ", ".join(f"{v:.4g}" for v in m["position_mm"])
        quat = ", ".join(f"{v:.4g}" for v in m["quat"])
        lines.append(_calibration_line(sn["calibration"], f"  {sn['name']}: mount ({pos}) mm, "
                                       f"quat ({quat}); calibration"))  # fmt: skip
    return lines


def format_experiment(s: dict) -> str:
    """What a person reads after the run: one line per run, then the times."""
    lines = _rig_lines(s["rig"]) if "rig" in s else [_calibration_line(s["calibration"])]
    per = s.get("provenance", {}).get("per")
    if per:
        lines.append(f"contact tables per {per} (as `camwhisker contact --per {per}`)")
    lines.append(f"  {'run':<24}{'role':<13}{'frames ok':>11}{'offset s':>10}{'estimates':>11}"
                 "  object")  # fmt: skip
    for r in s["runs"]:
        obj = r.get("percept", {}).get("object", "")
        name = f"{r['sensor']}/{r['name']}" if "sensor" in r else r["name"]
        lines.append(f"  {name:<24}{r['role']:<13}{r['ok']:>5} of {r['frames']:<3}"
                     f"{r['offset_s']:>+10.3f}{r['rows_with_estimate']:>11}  {obj}")  # fmt: skip
    if "space" in s:
        sp = s["space"]
        params = ", ".join(f"{k} {v:.4g}" for k, v in sp["params"].items())
        lines.append(f"in space ({len(sp['runs'])} runs, {sp['contacts']} contacts): "
                     f"{sp['model']}" + (f" ({params})" if params else ""))
    for name, why in s.get("failed", {}).items():
        lines.append(f"  {name}: contact failed: {why}")
    t = s["timings"]
    steps = (f"calibrate {t['calibrate']['seconds']:.1f} s, contact "
             f"{t['contact']['seconds']:.1f} s" if "calibrate" in t else
             f"calibrate and contact {t['calibrate_and_contact']['seconds']:.1f} s")  # fmt: skip
    lines.append(f"time: batch {t['batch']['seconds']:.1f} s ({t['batch']['frames']} frames, "
                 f"{t['batch']['reused']} tables reused), {steps}, "
                 f"percepts and plots {t['percept']['seconds']:.1f} s")  # fmt: skip
    return "\n".join(lines)
