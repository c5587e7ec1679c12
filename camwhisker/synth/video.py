"""Render a scenario to a real video file, with its truth table and provenance.

``.avi`` is Motion-JPEG, what a webcam delivers, written by OpenCV's MJPEG
encoder at the scenario's JPEG quality. ``.mp4`` is H.264 (libx264 through
PyAV, 4:4:4 chroma so that colours survive), what a recording usually is.
Every output is written to a temporary name and renamed into place, so a
crash never leaves a file that looks whole.

For ``NAME.avi`` the files are::

    NAME.avi           the video
    NAME.truth.csv     frame, t_s, dz_mm, phi_deg, theta_deg, sx_mm, sy_mm
    NAME.sensor.toml   the sensor file the scene was rendered with
    NAME.json          how it was made: version, scenario, artefacts, seed
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterable, Iterator
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np
from tqdm import tqdm

from camwhisker import __version__
from camwhisker.atomic import atomic_path
from camwhisker.sensor import Sensor, dump_sensor, sensor_to_dict
from camwhisker.synth.artefacts import apply_artefacts, illumination_field
from camwhisker.synth.render import SceneRenderer
from camwhisker.synth.scenarios import Scenario

__all__ = ["write_video", "render_frames", "render_scenario", "atomic_path", "sidecar_paths"]


def sidecar_paths(video: Path) -> dict[str, Path]:
    video = Path(video)
    stem = video.with_suffix("")
    return {
        "truth": stem.with_name(stem.name + ".truth.csv"),
        "sensor": stem.with_name(stem.name + ".sensor.toml"),
        "meta": stem.with_name(stem.name + ".json"),
    }


def write_video(
    path: Path,
    frames: Iterable[np.ndarray],
    fps: float,
    jpeg_quality: int | None = 88,
    h264_crf: int = 18,
) -> int:
    """Write uint8 BGR frames to ``.avi`` (MJPG, at ``jpeg_quality``) or ``.mp4``
    (H.264, at constant rate factor ``h264_crf``); returns the count."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".avi", ".mp4"):
        raise ValueError(f"{path}: video must end in .avi (MJPG) or .mp4 (H.264)")
    n = 0
    with atomic_path(path) as tmp:
        if suffix == ".avi":
            writer = None
            for frame in frames:
                if writer is None:
                    h, w = frame.shape[:2]
                    writer = cv2.VideoWriter(
                        str(tmp), cv2.CAP_OPENCV_MJPEG, cv2.VideoWriter_fourcc(*"MJPG"), fps, (w, h)
                    )
                    if not writer.isOpened():
                        raise RuntimeError(f"{path}: OpenCV could not open an MJPG writer")
                    writer.set(cv2.VIDEOWRITER_PROP_QUALITY, float(jpeg_quality or 95))
                writer.write(frame)
                n += 1
            if writer is not None:
                writer.release()
        else:
            with av.open(str(tmp), "w", format="mp4") as container:
                stream = None
                for frame in frames:
                    if stream is None:
                        stream = container.add_stream(
                            "libx264", rate=Fraction(fps).limit_denominator(1001)
                        )
                        stream.height, stream.width = frame.shape[:2]
                        stream.pix_fmt = "yuv444p"  # 4:2:0 shifts colours by ~3 DN
                        stream.options = {"crf": str(int(h264_crf)), "preset": "medium"}
                    packet = av.VideoFrame.from_ndarray(frame, format="bgr24")
                    container.mux(stream.encode(packet))
                    n += 1
                if stream is not None:
                    container.mux(stream.encode())
    return n


def render_frames(
    scenario: Scenario, sensor: Sensor, seed: int, progress: bool = False
) -> Iterator[np.ndarray]:
    """The camera's frames (uint8 BGR, before compression) for every pose of a scenario."""
    sensor = sensor.replace(**scenario.sensor_changes) if scenario.sensor_changes else sensor
    renderer = SceneRenderer(sensor)
    light = illumination_field(renderer.shape, scenario.artefacts)
    rng = np.random.default_rng(seed)
    track = scenario.track
    for i in tqdm(range(len(track)), desc=f"render {scenario.name}", disable=not progress):
        scene = renderer.geometry(track.pose(i))
        yield apply_artefacts(scene, float(track.t_s[i]), scenario.artefacts, rng, light)


def render_scenario(
    scenario: Scenario, sensor: Sensor, video: Path, seed: int, progress: bool = False
) -> dict[str, Path]:
    """Render a scenario to ``video`` plus its truth, sensor file and metadata sidecars."""
    video = Path(video)
    paths = sidecar_paths(video)
    used = sensor.replace(**scenario.sensor_changes) if scenario.sensor_changes else sensor
    art = scenario.artefacts
    frames = render_frames(scenario, sensor, seed, progress)
    n = write_video(video, frames, scenario.fps, art.jpeg_quality, art.h264_crf)
    with atomic_path(paths["truth"]) as tmp:
        scenario.track.write_csv(tmp)
    with atomic_path(paths["sensor"]) as tmp:
        tmp.write_text(dump_sensor(used))
    meta = {
        "camwhisker_version": __version__,
        "made_by": "camwhisker.synth.video.render_scenario",
        "scenario": scenario.name,
        "description": scenario.description,
        "seed": seed,
        "frames": n,
        "fps": scenario.fps,
        "codec": "MJPG" if video.suffix.lower() == ".avi" else "H.264",
        "artefacts": dataclasses.asdict(scenario.artefacts),
        "sensor": sensor_to_dict(used),
    }
    with atomic_path(paths["meta"]) as tmp:
        tmp.write_text(json.dumps(meta, indent=2) + "\n")
    return {"video": video, **paths}
