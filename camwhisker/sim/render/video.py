"""Render a scenario to a real video file, with its truth table and provenance.

``.avi`` is Motion-JPEG at the scenario's JPEG quality, ``.mp4`` is H.264
(:func:`camwhisker.io.video_out.write_video`). Every output is written to a
temporary name and renamed into place, so a crash never leaves a file that
looks whole.

For ``NAME.avi`` the files are::

    NAME.avi           the video
    NAME.truth.csv     frame, t_s, dz_mm, phi_deg, theta_deg, sx_mm, sy_mm
    NAME.sensor.toml   the sensor file the scene was rendered with
    NAME.json          how it was made: version, scenario, artefacts, seed (and
                       for a real build, its appearance and deviations)
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from camwhisker import __version__
from camwhisker.files import jsonfile
from camwhisker.files.atomic import atomic_path
from camwhisker.io.video_out import write_video
from camwhisker.sensor.file import Sensor, dump_sensor, sensor_to_dict
from camwhisker.sim.render.artefacts import apply_artefacts, illumination_field
from camwhisker.sim.render.render import Appearance, SceneRenderer
from camwhisker.sim.render.scenarios import Scenario

if TYPE_CHECKING:
    from camwhisker.sim.render.builds import Build

__all__ = ["write_video", "render_frames", "render_scenario", "atomic_path", "sidecar_paths"]


def sidecar_paths(video: Path) -> dict[str, Path]:
    video = Path(video)
    stem = video.with_suffix("")
    return {
        "truth": stem.with_name(stem.name + ".truth.csv"),
        "sensor": stem.with_name(stem.name + ".sensor.toml"),
        "meta": stem.with_name(stem.name + ".json"),
    }


def render_frames(
    scenario: Scenario,
    sensor: Sensor,
    seed: int,
    progress: bool = False,
    appearance: Appearance | None = None,
) -> Iterator[np.ndarray]:
    """The camera's frames (uint8 BGR, before compression) for every pose of a scenario."""
    sensor = sensor.replace(**scenario.sensor_changes) if scenario.sensor_changes else sensor
    renderer = SceneRenderer(sensor, appearance)
    light = illumination_field(renderer.shape, scenario.artefacts)
    rng = np.random.default_rng(seed)
    track = scenario.track
    held, scene = None, None
    for i in tqdm(range(len(track)), desc=f"render {scenario.name}", disable=not progress):
        pose = track.pose(i)
        if pose != held:  # a pose held over frames (rests, pauses) is drawn once
            held, scene = pose, renderer.geometry(pose)
        yield apply_artefacts(scene, float(track.t_s[i]), scenario.artefacts, rng, light)


def render_scenario(
    scenario: Scenario,
    sensor: Sensor,
    video: Path,
    seed: int,
    progress: bool = False,
    build: Build | None = None,
) -> dict[str, Path]:
    """Render a scenario to ``video`` plus its truth, sensor file and metadata sidecars.

    With a ``build`` (:func:`camwhisker.sim.render.builds.draw_build`), the scene is
    drawn with the build's own sensor, appearance and webcam instead of
    ``sensor`` and the scenario's; the sensor sidecar is the build's true file
    and the metadata describe the build.
    """
    if build is not None:
        scenario, sensor = build.scenario(scenario), build.sensor
    video = Path(video)
    paths = sidecar_paths(video)
    used = sensor.replace(**scenario.sensor_changes) if scenario.sensor_changes else sensor
    art = scenario.artefacts
    appearance = None if build is None else build.appearance
    frames = render_frames(scenario, sensor, seed, progress, appearance)
    n = write_video(video, frames, scenario.fps, art.jpeg_quality, art.h264_crf)
    with atomic_path(paths["truth"]) as tmp:
        scenario.track.write_csv(tmp)
    with atomic_path(paths["sensor"]) as tmp:
        tmp.write_text(dump_sensor(used))
    meta = {
        "camwhisker_version": __version__,
        "made_by": "camwhisker.sim.render.video.render_scenario",
        "scenario": scenario.name,
        "description": scenario.description,
        "seed": seed,
        "frames": n,
        "fps": scenario.fps,
        "codec": "MJPG" if video.suffix.lower() == ".avi" else "H.264",
        "artefacts": dataclasses.asdict(scenario.artefacts),
        "sensor": sensor_to_dict(used),
    }
    if build is not None:
        meta["build"] = build.describe()
    with atomic_path(paths["meta"]) as tmp:
        tmp.write_text(jsonfile.dumps(meta, indent=2) + "\n")
    return {"video": video, **paths}
