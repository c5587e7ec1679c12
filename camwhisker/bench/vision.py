"""Front-end benchmark: speed and accuracy, default (exact model) beside paper mode.

Renders a fixed set of scenes with fixed seeds to MJPG (or H.264) videos in a
temporary folder, decodes every frame into memory, then times the front end
on one core (``cv2.setNumThreads(1)``), decode excluded, and compares its
output with the renderer's truth. Prints one Markdown table.

    camwhisker dev vision-bench [--frames 60] [--scenes nominal,distortion,hard]

Columns: frames/s of the whole front end (white balance to pose, the first
frame's detection excluded) by wall clock and by this process's CPU time (the
steadier figure on a shared machine), share of rows ok, RMSE of phi and dz over the
ok rows, theta MAE where phi >= 2 deg, mean phi error where phi > 15 deg
(bias), and the same errors for the paper's eqs. 2-7 on the same frames.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from camwhisker.io.sources import VideoSource
from camwhisker.sensor.file import Sensor
from camwhisker.sim.render.scenarios import Scenario, make_scenario, wrap_deg
from camwhisker.sim.render.video import render_scenario, sidecar_paths
from camwhisker.vision.tracker import FrontEnd, FrontEndOptions

__all__ = ["SCENES", "BenchRow", "RenderedScene", "render_scene", "scene_errors", "run_scene",
           "main"]  # fmt: skip

#: Scenes and their seeds (never used to tune the front end).
SCENES = {"nominal": 2001, "distortion": 2002, "hard": 2003}


@dataclass(frozen=True)
class BenchRow:
    scene: str
    mode: str
    frames: int
    fps: float
    fps_cpu: float
    ok: float
    phi_rmse_deg: float
    dz_rmse_mm: float
    theta_mae_deg: float
    phi_bias_deg: float


@dataclass(frozen=True)
class RenderedScene:
    """A benchmark scene on disk: its scenario (truth), the sensor it was seen with,
    and the video."""

    name: str
    seed: int
    scenario: Scenario
    sensor: Sensor
    video: Path


def render_scene(name: str, seed: int, n_frames: int, folder: Path,
                 suffix: str = ".avi") -> RenderedScene:  # fmt: skip
    """Render scene ``name`` with ``seed`` to ``folder``, or reuse an earlier render there.

    The file name carries the scene, seed and frame count, so a cache folder
    shared between runs only ever reuses the same frames."""
    scenario = make_scenario(name, n_frames, seed)
    video = Path(folder) / f"{name}-s{seed}-n{n_frames}{suffix}"
    if not (video.exists() and sidecar_paths(video)["meta"].exists()):
        video.parent.mkdir(parents=True, exist_ok=True)
        render_scenario(scenario, Sensor(), video, seed)
    sensor = Sensor()
    if scenario.sensor_changes:
        sensor = sensor.replace(**scenario.sensor_changes)
    return RenderedScene(name, seed, scenario, sensor, video)


def scene_errors(track, dz, phi, theta, ok):
    """(phi RMSE deg, dz RMSE mm, theta MAE deg where phi >= 2, phi bias deg where
    phi > 15) of estimates against the truth ``track`` over the rows ``ok``."""
    return _errors(track, dz, phi, theta, ok)


def _errors(track, dz, phi, theta, ok):
    e_phi, e_dz = phi - track.phi_deg, dz - track.dz_mm
    big = ok & (track.phi_deg >= 2.0) & np.isfinite(theta)
    steep = ok & (track.phi_deg > 15.0)

    def rms(e):
        m = ok & np.isfinite(e)
        return float(np.sqrt(np.mean(e[m] ** 2))) if m.any() else math.nan

    mae = math.nan
    if big.any():
        mae = float(np.mean(np.abs(wrap_deg(theta[big] - track.theta_deg[big]))))
    bias = float(np.mean(e_phi[steep])) if steep.any() else math.nan
    return rms(e_phi), rms(e_dz), mae, bias


def run_scene(name: str, seed: int, n_frames: int, folder: Path, suffix: str = ".avi",
              options: FrontEndOptions | None = None) -> list[BenchRow]:  # fmt: skip
    """Render one scene, run the front end on it, return the model and paper rows."""
    scene = render_scene(name, seed, n_frames, folder, suffix)
    scenario, sensor = scene.scenario, scene.sensor
    frames = [f.image for f in VideoSource(scene.video)]
    track = scenario.track
    cv2.setNumThreads(1)
    fe = FrontEnd(sensor, options or FrontEndOptions())
    results = [fe.start(frames[0])]
    t0, c0 = time.perf_counter(), time.process_time()
    results += [fe.update(f) for f in frames[1:]]
    elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
    fps, fps_cpu = (len(frames) - 1) / elapsed, (len(frames) - 1) / cpu
    ok = np.array([r.ok for r in results])
    rows = []
    for mode, k in (("model", "model"), ("paper", "paper")):
        vals = np.array([getattr(r, k) for r in results], dtype=float)
        dz, phi, theta = vals[:, 0], vals[:, 1], vals[:, 2]
        ok_mode = ok & np.isfinite(phi)
        rows.append(BenchRow(name, mode, len(frames), fps, fps_cpu, float(ok_mode.mean()),
                             *_errors(track, dz, phi, theta, ok_mode)))  # fmt: skip
    return rows


def table(rows: list[BenchRow]) -> str:
    head = ("| scene | mode | frames | frames/s (wall) | frames/s (CPU) | ok | phi RMSE (deg) "
            "| dz RMSE (mm) | theta MAE, phi>=2 (deg) | phi bias, phi>15 (deg) |")  # fmt: skip
    lines = [head, "|" + "---|" * 10]
    for r in rows:
        lines.append(
            f"| {r.scene} | {r.mode} | {r.frames} | {r.fps:.0f} | {r.fps_cpu:.0f} "
            f"| {100 * r.ok:.0f}% | {r.phi_rmse_deg:.4f} | {r.dz_rmse_mm:.4f} "
            f"| {r.theta_mae_deg:.3f} | {r.phi_bias_deg:+.4f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="camwhisker dev vision-bench", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--frames", type=int, default=60, help="frames per scene")
    p.add_argument("--scenes", default=",".join(SCENES), help="comma-separated scene names")
    p.add_argument("--codec", choices=("avi", "mp4"), default="avi", help="MJPG AVI or H.264")
    p.add_argument("--no-shift", action="store_true", help="fit without the lateral shift")
    args = p.parse_args(argv)
    options = FrontEndOptions(fit_shift=not args.no_shift)
    rows = []
    with tempfile.TemporaryDirectory(prefix="camwhisker-bench-") as tmp:
        for name in args.scenes.split(","):
            if name not in SCENES:
                p.error(f"unknown scene {name!r} (known: {', '.join(SCENES)})")
            rows += run_scene(name, SCENES[name], args.frames, Path(tmp), f".{args.codec}", options)
    print(table(rows))
    print(f"\n{args.frames} frames per scene, seeds {SCENES}, {args.codec}, one core, "
          f"decode excluded; options {options}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
