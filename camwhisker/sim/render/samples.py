"""The bundled sample videos in ``sample_frames/``: what they are and how to make them again.

``camwhisker dev make-samples`` (or :func:`make_samples`) regenerates every file
bit for bit from the names, frame counts and seeds below, and the hand-made
build of ``sample_frames/build/`` (:data:`BUILD_SEED`): a calibration sweep, a
separate clip, the build's true sensor file and its square's side as measured
with calipers (:data:`CALIPER_FILE`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camwhisker.files.atomic import atomic_write_text
from camwhisker.io.signals import read_signal_table
from camwhisker.io.sources import VideoSource
from camwhisker.sensor.file import Sensor, dump_sensor
from camwhisker.sim.render.builds import draw_build
from camwhisker.sim.render.scenarios import PoseTrack, make_scenario
from camwhisker.sim.render.video import render_scenario, sidecar_paths

__all__ = ["Sample", "SAMPLES", "BUILD_SEED", "BUILD_DIR", "BUILD_SAMPLES", "TRUE_SENSOR_FILE",
           "CALIPER_FILE", "make_samples", "make_build_sample", "caliper_side_mm",
           "describe_video", "truth_errors"]  # fmt: skip


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

#: A held-out build of the reality suite: a sample to show the workflow on, nothing is tuned on it.
BUILD_SEED = 150
BUILD_DIR = "build"
#: The sweep for calibrate-sensor (12 s at 30 frames/s) and a separate recording of the
#: same build (render seed: the build's + 1000, as the calibration benchmark's clip).
BUILD_SAMPLES = (
    Sample("sweep.mp4", "calibration_sweep", 360, BUILD_SEED),
    Sample("clip.mp4", "rest_bracketed", 150, BUILD_SEED + 1000),
)
TRUE_SENSOR_FILE = "true.sensor.toml"
CALIPER_FILE = "caliper.txt"


def make_samples(dest: Path, progress: bool = True) -> list[Path]:
    """Render every sample and the hand-made build into ``dest``; returns the video paths."""
    out = []
    for s in SAMPLES:
        scenario = make_scenario(s.scenario, s.frames, s.seed)
        paths = render_scenario(scenario, Sensor(), Path(dest) / s.file, s.seed, progress)
        out.append(paths["video"])
    return out + make_build_sample(Path(dest) / BUILD_DIR, progress)


def make_build_sample(folder: Path, progress: bool = True) -> list[Path]:
    """Render build :data:`BUILD_SEED`'s videos into ``folder`` with its true sensor file
    and caliper reading; returns the video paths."""
    folder = Path(folder)
    build = draw_build(BUILD_SEED)
    out = []
    for s in BUILD_SAMPLES:
        scenario = make_scenario(s.scenario, s.frames, s.seed)
        paths = render_scenario(scenario, build.sensor, folder / s.file, s.seed, progress, build)
        paths["sensor"].unlink()  # the one true file below serves both videos
        out.append(paths["video"])
    atomic_write_text(folder / TRUE_SENSOR_FILE, dump_sensor(build.sensor))
    side_mm = round(build.sensor.plate.square_side_mm, 2)  # what calipers read
    atomic_write_text(folder / CALIPER_FILE, "# The square's side as measured with calipers "
                      f"(mm): calibrate-sensor --square-side-mm\n{side_mm:.2f}\n")  # fmt: skip
    return out


def caliper_side_mm(path: Path) -> float:
    """The square's side (mm) in a caliper file: its one line that is not a comment."""
    lines = [ln.strip() for ln in Path(path).read_text().splitlines()]
    values = [ln for ln in lines if ln and not ln.startswith("#")]
    if len(values) != 1:
        raise ValueError(f"{path}: expected one line with the side in mm, got {len(values)}")
    try:
        return float(values[0])
    except ValueError:
        raise ValueError(f"{path}: not a number of mm: {values[0]!r}") from None


def describe_video(path: Path, signals: Path | None = None) -> dict:
    """What a video holds, decoded as batch decodes it (frames decoded against the
    container's count, ``warning`` where they differ), and the truth beside it if there
    is one; with ``signals`` (its signal table), that table's :func:`truth_errors` too.

    Raises
    ------
    FileNotFoundError, camwhisker.io.sources.SourceError
        No such file, or not a video.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such video")
    source = VideoSource(path)
    info = {"path": str(path), "fps": source.fps, "width_px": source.frame_size[0],
            "height_px": source.frame_size[1]}
    for _ in source:  # decoded as batch decodes it, past a corrupt stretch
        pass
    info["frames_decoded"] = source.frames_read
    info["frames_in_container"] = len(source) or None
    if source.problem:
        info["warning"] = source.problem
    truth = sidecar_paths(path)["truth"]
    if truth.is_file():
        track = PoseTrack.read_csv(truth)
        info["truth"] = str(truth)
        for name in ("dz_mm", "phi_deg", "sx_mm", "sy_mm"):
            values = getattr(track, name)
            info[f"{name}_range"] = (float(values.min()) + 0.0, float(values.max()) + 0.0)
    if signals is not None:
        if not truth.is_file():
            raise FileNotFoundError(f"{path}: no truth beside it ({truth}) to hold {signals} to")
        info["signals"] = str(signals)
        info.update(truth_errors(Path(signals), truth))
    return info


def truth_errors(signals: Path, truth: Path) -> dict:
    """A signal table's errors against the truth, over its ok rows (matched by frame).

    Returns the share of ok rows, phi RMSE (deg) and dz RMSE (mm); NaN where no row is ok.
    """
    table = read_signal_table(signals)
    track = PoseTrack.read_csv(truth)
    frame = table["frame"]
    bad = np.flatnonzero(~np.isfinite(frame) | (frame < 0) | (frame >= len(track)))
    if bad.size:
        raise ValueError(f"{signals}: row {bad[0] + 2}, frame {frame[bad[0]]:g} is not in "
                         f"{truth} ({len(track)} frames)")  # fmt: skip
    index = frame.astype(int)
    ok = table["ok"]
    e_phi = table["phi_deg"][ok] - track.phi_deg[index[ok]]
    e_dz = table["dz_mm"][ok] - track.dz_mm[index[ok]]
    nan = float("nan")
    return {
        "ok_share": float(ok.mean()),
        "phi_rmse_deg": float(np.sqrt(np.mean(e_phi**2))) if ok.any() else nan,
        "dz_rmse_mm": float(np.sqrt(np.mean(e_dz**2))) if ok.any() else nan,
    }
