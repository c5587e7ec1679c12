"""The bundled sample videos in ``sample_frames/``: what they are and how to make them again.

``camwhisker make-samples`` (or :func:`make_samples`) regenerates every file
bit for bit from the names, frame counts and seeds below.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2

from camwhisker.sensor import Sensor
from camwhisker.synth.scenarios import PoseTrack, make_scenario
from camwhisker.synth.video import render_scenario, sidecar_paths

__all__ = ["Sample", "SAMPLES", "make_samples", "describe_video"]


@dataclass(frozen=True)
class Sample:
    file: str
    scenario: str
    frames: int
    seed: int


#: Small enough to bundle (a few MB in all): H.264 for the longer clips, one
#: short MJPG clip as a webcam delivers it.
SAMPLES = (
    Sample("nominal.mp4", "nominal", 90, 101),
    Sample("distortion.mp4", "distortion", 60, 102),
    Sample("hard.mp4", "hard", 40, 103),
    Sample("nominal_mjpg.avi", "nominal", 12, 104),
)


def make_samples(dest: Path, progress: bool = True) -> list[Path]:
    """Render every sample into ``dest``; returns the video paths."""
    out = []
    for s in SAMPLES:
        scenario = make_scenario(s.scenario, s.frames, s.seed)
        paths = render_scenario(scenario, Sensor(), Path(dest) / s.file, s.seed, progress)
        out.append(paths["video"])
    return out


def describe_video(path: Path) -> dict:
    """What a video holds, as decoded by OpenCV, and the truth beside it if there is one."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such video")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise ValueError(f"{path}: OpenCV cannot open it as a video")
    info = {
        "path": str(path),
        "backend": cap.getBackendName(),
        "fps": cap.get(cv2.CAP_PROP_FPS),
        "width_px": int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)),
        "height_px": int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)),
    }
    n = 0
    while cap.grab():
        n += 1
    cap.release()
    info["frames_decoded"] = n
    truth = sidecar_paths(path)["truth"]
    if truth.is_file():
        track = PoseTrack.read_csv(truth)
        info["truth"] = str(truth)
        for name in ("dz_mm", "phi_deg", "sx_mm", "sy_mm"):
            values = getattr(track, name)
            info[f"{name}_range"] = (float(values.min()) + 0.0, float(values.max()) + 0.0)
    return info
