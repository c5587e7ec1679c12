"""A simulated stage experiment filmed: the mechanics drive the renderer.

The quasi-static whisker simulator (:mod:`camwhisker.sim.mechanics`) gives, for
each run, the plate's phi and dz on the camera's clock and the stage log on
the stage's own clock, offset by a few seconds. This module renders those
poses as webcam video and writes, per run ``NAME``::

    NAME.mp4                 the video (H.264), with NAME.truth.csv (pose per frame),
                             NAME.sensor.toml and NAME.json as for any render
    NAME.stage.csv           the stage log, header t_s,x_mm[,r_mm] (docs/sensor.md section 7)
    NAME.contact_truth.csv   contact truth per frame: r, contact point, slipping

and ``experiment.toml``, the manifest: each run's role (calibration,
compliant, box, bottle), its simulator kind and name, and the true clock
offset (for checking only; the chain estimates it).

Sizing (the bundle must stay small): at :data:`EXPERIMENT_FPS` = 3 frames/s
each 1.2-1.8 s stage pause holds 3-5 frames, enough for the per-pause
medians the paper uses, and H.264 at constant rate factor
:data:`EXPERIMENT_CRF` = 26 keeps a frame near 6 KB. The whole campaign
(8 calibration radii, 3 compliant pegs, the box, the bottle from both sides)
is about 2,700 frames and 18 MB.
"""

from __future__ import annotations

import tomllib
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from camwhisker import __version__
from camwhisker.files.atomic import atomic_path
from camwhisker.files.tables import write_csv
from camwhisker.sensor.file import Sensor
from camwhisker.sim.mechanics import StageProtocol, simulate_runs
from camwhisker.sim.mechanics.files import TRUTH_COLUMNS
from camwhisker.sim.render.scenarios import NOMINAL_ARTEFACTS, PoseTrack, Scenario
from camwhisker.sim.render.video import render_scenario

__all__ = [
    "ROLES",
    "EXPERIMENT_FPS",
    "EXPERIMENT_CRF",
    "ExperimentRun",
    "pose_track",
    "render_run",
    "render_experiment",
    "read_experiment",
]

#: Role in the chain -> simulator kind (camwhisker.sim.mechanics.KINDS).
ROLES = {
    "calibration": "rigid",
    "compliant": "compliant",
    "box": "slide-box",
    "bottle": "slide-circle",
}
#: Frame rate of the filmed runs: 3-5 frames per stage pause (module docstring).
EXPERIMENT_FPS = 3.0
#: H.264 constant rate factor: a frame near 6 KB, so the bundle stays small.
EXPERIMENT_CRF = 26


@dataclass(frozen=True)
class ExperimentRun:
    """One run of a filmed experiment, as listed in ``experiment.toml`` (paths resolved)."""

    role: str
    kind: str
    name: str
    video: Path
    stage: Path
    contact_truth: Path
    offset_s: float


def pose_track(run) -> PoseTrack:
    """The plate's pose per camera frame of a simulated stage run, for the renderer."""
    t = run.truth["t_s"]
    phi = np.nan_to_num(run.truth["phi_deg"])
    dz = np.nan_to_num(run.truth["dz_mm"])
    zeros = np.zeros_like(t)
    theta = np.full_like(t, run.info["theta_deg"])
    return PoseTrack(t, dz, phi, theta, zeros, zeros.copy())


def render_run(args) -> dict:
    """Film one stage run: ``args`` (role, run, dest, fps, artefacts, seed), a tuple for a
    process pool; its manifest entry."""
    role, run, dest, fps, artefacts, seed = args
    stem = f"{role}_{run.name}"
    scenario = Scenario(
        stem,
        f"{role} run {run.name} ({run.kind}) of a simulated stage experiment",
        pose_track(run),
        artefacts,
        fps,
    )
    render_scenario(scenario, Sensor(), dest / f"{stem}.mp4", seed)
    stage_cols = {k: run.stage[k] for k in ("t_s", "x_mm", "r_mm") if k in run.stage}
    write_csv(dest / f"{stem}.stage.csv", stage_cols, digits=10)
    write_csv(dest / f"{stem}.contact_truth.csv", {k: run.truth[k] for k in TRUTH_COLUMNS}, 8)
    return {
        "role": role,
        "kind": run.kind,
        "name": run.name,
        "video": f"{stem}.mp4",
        "stage": f"{stem}.stage.csv",
        "contact_truth": f"{stem}.contact_truth.csv",
        "offset_s": float(run.offset_s),
        "frames": int(run.truth["t_s"].size),
    }


def render_experiment(
    dest: Path,
    seed: int,
    roles: dict[str, str] | None = None,
    fps: float = EXPERIMENT_FPS,
    crf: int = EXPERIMENT_CRF,
    jobs: int = 2,
) -> Path:
    """Simulate and film a stage experiment into ``dest``; returns the manifest path.

    Parameters
    ----------
    roles : dict, optional
        Role -> simulator kind; default :data:`ROLES` (the whole campaign).
    jobs : int
        Runs rendered in parallel processes.
    """
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    roles = roles or ROLES
    artefacts = replace(NOMINAL_ARTEFACTS, h264_crf=crf)
    protocol = StageProtocol(fps=fps)
    work = []
    for i, (role, kind) in enumerate(roles.items()):
        for j, run in enumerate(simulate_runs(kind, seed + 1000 * i, protocol=protocol)):
            work.append((role, run, dest, fps, artefacts, seed + 1000 * i + j))
    if jobs > 1:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            entries = list(pool.map(render_run, work))
    else:
        entries = [render_run(w) for w in work]
    lines = [
        "# A simulated stage experiment, filmed (camwhisker.sim.render.experiment).",
        "# offset_s is the true clock offset (t_camera = t_stage + offset_s), for checking only.",
        f'version = "{__version__}"',
        f"seed = {int(seed)}",
        f"fps = {float(fps)}",
        f"h264_crf = {int(crf)}",
        "",
    ]
    for e in entries:
        lines.append("[[runs]]")
        for key, value in e.items():
            lines.append(
                f"{key} = {value!r}" if not isinstance(value, str) else f'{key} = "{value}"'
            )
        lines.append("")
    manifest = dest / "experiment.toml"
    with atomic_path(manifest) as tmp:
        tmp.write_text("\n".join(lines))
    return manifest


def read_experiment(folder: Path) -> list[ExperimentRun]:
    """The runs of a filmed experiment, from its ``experiment.toml``."""
    folder = Path(folder)
    manifest = folder / "experiment.toml"
    try:
        data = tomllib.loads(manifest.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"{manifest}: no experiment manifest here") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{manifest}: not valid TOML ({exc})") from exc
    runs = []
    for i, r in enumerate(data.get("runs", [])):
        try:
            runs.append(
                ExperimentRun(
                    r["role"],
                    r["kind"],
                    r["name"],
                    folder / r["video"],
                    folder / r["stage"],
                    folder / r["contact_truth"],
                    float(r["offset_s"]),
                )  # fmt: skip
            )
        except KeyError as exc:
            raise ValueError(f"{manifest}: run {i} lacks key {exc}") from None
    if not runs:
        raise ValueError(f"{manifest}: lists no runs")
    return runs
