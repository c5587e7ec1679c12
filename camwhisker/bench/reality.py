"""Reality benchmark: the front end on hand-made builds, with their true and the nominal file.

Renders short clips of one scene seen by builds of the reality suite
(:data:`camwhisker.synth.builds.REALITY_SUITE`; its held-out seeds by
default), runs the front end on each with (a) the build's true sensor file and
(b) the nominal file, and prints one Markdown table: whether the first frame's
features were found, the share of rows ok, and phi and dz RMSE over the ok rows.

    python -m camwhisker.bench.reality [--seeds 100-104] [--scene nominal] [--frames 30]
"""

from __future__ import annotations

import argparse
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camwhisker.bench.vision import scene_errors
from camwhisker.sensor import Sensor
from camwhisker.sources import VideoSource
from camwhisker.stream import track
from camwhisker.synth.builds import REALITY_SUITE, Build, draw_build
from camwhisker.synth.scenarios import Scenario, make_scenario
from camwhisker.synth.video import render_scenario, sidecar_paths
from camwhisker.vision.detect import FeaturesNotFound

__all__ = ["RealityRow", "render_build_clip", "clip_row", "run_build", "table", "seed_list", "main"]


@dataclass(frozen=True)
class RealityRow:
    seed: int
    sensor_file: str  # "true" or "nominal"
    detected: bool
    ok: float
    phi_rmse_deg: float
    dz_rmse_mm: float
    note: str = ""


def render_build_clip(build: Build, scene: str, n_frames: int, render_seed: int,
                      folder: Path) -> tuple[Scenario, Path]:  # fmt: skip
    """Build ``build`` seeing ``scene`` rendered into ``folder``; a clip already there is reused.

    ``render_seed`` seeds both the scene's poses and the render's noise.
    """
    scenario = build.scenario(make_scenario(scene, n_frames, render_seed))
    video = Path(folder) / f"{scene}-build{build.seed}-n{n_frames}-r{render_seed}.avi"
    if not (video.exists() and sidecar_paths(video)["meta"].exists()):
        render_scenario(scenario, build.sensor, video, render_seed, build=build)
    return scenario, video


def clip_row(seed: int, label: str, frames: list, scenario: Scenario,
             sensor: Sensor) -> RealityRow:  # fmt: skip
    """Run the front end with ``sensor`` on a rendered clip and score it against its poses."""
    try:
        results = list(track(frames, sensor))
    except FeaturesNotFound as exc:
        return RealityRow(seed, label, False, 0.0, math.nan, math.nan, str(exc))
    ok = np.array([r.ok for r in results])
    vals = np.array([r.model for r in results], dtype=float)
    dz, phi, theta = vals.T
    trusted = ok & np.isfinite(phi)
    phi_rmse, dz_rmse, _, _ = scene_errors(scenario.track, dz, phi, theta, trusted)
    return RealityRow(seed, label, True, float(ok.mean()), phi_rmse, dz_rmse)


def run_build(seed: int, scene: str, n_frames: int, folder: Path,
              nominal: Sensor | None = None) -> list[RealityRow]:  # fmt: skip
    """Render build ``seed`` seeing ``scene`` and run the front end with both files."""
    nominal = nominal or Sensor()
    build = draw_build(seed, nominal)
    scenario, video = render_build_clip(build, scene, n_frames, seed, folder)
    frames = [f.image for f in VideoSource(video)]
    return [clip_row(seed, label, frames, scenario, sensor)
            for label, sensor in (("true", build.sensor), ("nominal", nominal))]  # fmt: skip


def table(rows: list[RealityRow]) -> str:
    lines = ["| build | sensor file | detected | ok | phi RMSE (deg) | dz RMSE (mm) | note |",
             "|" + "---|" * 7]  # fmt: skip
    for r in rows:
        lines.append(
            f"| {r.seed} | {r.sensor_file} | {'yes' if r.detected else 'no'} "
            f"| {100 * r.ok:.0f}% | {r.phi_rmse_deg:.4f} | {r.dz_rmse_mm:.4f} | {r.note} |"
        )
    return "\n".join(lines)


def seed_list(text: str) -> list[int]:
    """'100-104' or '100,101,107'."""
    if "-" in text:
        lo, hi = (int(x) for x in text.split("-"))
        return list(range(lo, hi + 1))
    return [int(x) for x in text.split(",")]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m camwhisker.bench.reality", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    held = REALITY_SUITE.held_out_seeds
    p.add_argument("--seeds", default=f"{held[0]}-{held[4]}", help="e.g. 100-104 or 100,107")
    p.add_argument("--scene", default=REALITY_SUITE.scenes[0], help="scenario name")
    p.add_argument("--frames", type=int, default=30, help="frames per clip")
    args = p.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="camwhisker-reality-") as tmp:
        for seed in seed_list(args.seeds):
            rows += run_build(seed, args.scene, args.frames, Path(tmp))
    print(table(rows))
    print(f"\nscene {args.scene}, {args.frames} frames per build (MJPG), seeds {args.seeds}; "
          f"tune only on seeds {REALITY_SUITE.tuning_seeds}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
