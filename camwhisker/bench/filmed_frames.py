"""Per-frame contact on filmed sweeps: the targets, through the front end.

:mod:`camwhisker.bench.frames` scores the contact chain on the simulator's
signals with Gaussian noise. Here the same runs (every contact kind, paused or
swept at a constant speed) are filmed on a hand-made build
(:func:`~camwhisker.sim.render.builds.draw_build`: its own camera, geometry, look
and webcam), written as MJPG, decoded and tracked with the build's true sensor
file as ``batch`` does, and the tracker's signal table goes through
:func:`~camwhisker.contact.pipeline.contact_rows` (frame mode, clock offset
estimated) and is scored as there. The calibration is the simulated one at the
front end's noise target (:data:`~camwhisker.sim.mechanics.experiment.FRONT_END_NOISE`),
as in ``contact-bench``: MF's phi floor is the one a user's calibration at that
noise would set.

    camwhisker dev filmed-frames-bench [--builds 100] [--speeds 1,5] [--cache DIR]

Builds are those of :data:`~camwhisker.sim.render.builds.REALITY_SUITE`; none of this
bench's numbers were used to choose a constant.
"""

from __future__ import annotations

import argparse
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from tqdm import tqdm

from camwhisker.bench.contact import calibrate_simulated
from camwhisker.bench.frames import format_frames, frame_runs, score_frames
from camwhisker.bench.seeds import seed_list
from camwhisker.io.sources import VideoSource
from camwhisker.sim.mechanics.experiment import FRONT_END_NOISE, StageProtocol
from camwhisker.sim.render.builds import REALITY_SUITE, draw_build
from camwhisker.sim.render.experiment import pose_track
from camwhisker.sim.render.scenarios import NOMINAL_ARTEFACTS, Scenario
from camwhisker.sim.render.video import render_scenario, sidecar_paths
from camwhisker.vision.stream import REST_FRAMES, stream
from camwhisker.vision.tracker import FrontEndOptions

__all__ = ["film_run", "filmed_scores", "main"]

#: The runs' camera rate: the videos play at it.
FPS = StageProtocol.fps


def film_run(kind: str, run, build_seed: int, render_seed: int, video: Path) -> dict:
    """A run filmed by build ``build_seed`` into ``video`` (reused when there) and tracked:
    its signal table (t_s on the run's camera clock) and the tracker's phi and dz RMSE."""
    build = draw_build(build_seed)
    if not (video.exists() and sidecar_paths(video)["meta"].exists()):
        scenario = Scenario(video.stem, f"{kind} run {run.name}, filmed by build {build_seed}",
                            pose_track(run), NOMINAL_ARTEFACTS, FPS)
        render_scenario(scenario, build.sensor, video, render_seed, build=build)
    frames = VideoSource(video, decode_threads=1)
    options = FrontEndOptions(rest_frames=REST_FRAMES)
    results = [r for _, r in stream(frames, build.sensor, options)]
    t = np.asarray(run.truth["t_s"], float)
    if len(results) != t.size:
        raise RuntimeError(f"{video}: {len(results)} frames tracked, the run has {t.size}")
    ok = np.array([r.ok for r in results])
    dz, phi, theta = np.array([r.model for r in results], dtype=float).T
    phi, dz, theta = (np.where(ok, v, np.nan) for v in (phi, dz, theta))
    e_phi = phi - run.truth["phi_deg"]
    e_dz = dz - run.truth["dz_mm"]
    return {"signals": {"t_s": t, "phi_deg": phi, "dz_mm": dz, "theta_deg": theta,
                        "ok": ok.astype(int)},
            "phi_rmse_deg": float(np.sqrt(np.nanmean(e_phi**2))),
            "dz_rmse_mm": float(np.sqrt(np.nanmean(e_dz**2)))}


def _film(args) -> dict:
    return film_run(*args)


def filmed_scores(build_seed: int, speed_mm_s: float | None, folder: Path, seed: int = 0,
                  jobs: int = 2) -> dict:
    """:func:`~camwhisker.bench.frames.score_frames` of runs of ``seed + 1`` filmed by a build,
    calibrated on simulated rigid runs of ``seed``; adds the tracker's RMSE over the runs."""
    calib = calibrate_simulated(seed, noise=FRONT_END_NOISE)
    runs = frame_runs(seed + 1, speed_mm_s)
    tag = "paused" if speed_mm_s is None else f"{speed_mm_s:g}mms"
    # Each run's own render noise: the build's seed and the run's place.
    work = [(kind, run, build_seed, 1000 * build_seed + i,
             Path(folder) / f"b{build_seed}-s{seed + 1}-{tag}-{kind}-{i}.avi")
            for i, (kind, run) in enumerate(runs)]
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        filmed = list(tqdm(pool.map(_film, work), total=len(work), unit="run",
                           desc=f"build {build_seed}, {tag}"))
    out = score_frames(calib, runs, [f["signals"] for f in filmed], speed_mm_s)
    out["phi_rmse_deg"] = float(np.sqrt(np.mean([f["phi_rmse_deg"] ** 2 for f in filmed])))
    out["dz_rmse_mm"] = float(np.sqrt(np.mean([f["dz_rmse_mm"] ** 2 for f in filmed])))
    out["build"] = build_seed
    return out


def _speeds(text: str) -> list[float | None]:
    return [None if s.strip() == "paused" else float(s) for s in text.split(",")]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="camwhisker dev filmed-frames-bench",
                                description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--builds", type=seed_list, default=str(REALITY_SUITE.held_out_seeds[0]),
                   help="hand-made builds, e.g. 100 or 100-102 (default: 100)")
    p.add_argument("--speeds", type=_speeds, default="1,5",
                   help="base speeds (mm/s), 'paused' for the paper's pauses (default: 1,5)")
    p.add_argument("--seed", type=int, default=0,
                   help="calibration seed; the runs are seed + 1's (default: 0)")
    p.add_argument("--jobs", type=int, default=2, help="runs filmed in parallel (default: 2)")
    p.add_argument("--cache", type=Path, help="keep the videos here (reused when present)")
    args = p.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="camwhisker-filmed-") as tmp:
        folder = args.cache or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for build in args.builds:
            for speed in args.speeds:
                rows.append(filmed_scores(build, speed, folder, args.seed, args.jobs))
    for build in args.builds:
        mine = [r for r in rows if r["build"] == build]
        print(f"build {build} (true sensor file), runs of seed {args.seed + 1} at {FPS:g} "
              f"frames/s, MJPG; calibration: simulated, seed {args.seed}, front-end noise")
        for line in format_frames(mine):
            print("  " + line)
        for r in mine:
            name = "paused" if r["speed_mm_s"] is None else f"{r['speed_mm_s']:g} mm/s"
            print(f"  {name}: tracker RMSE phi {r['phi_rmse_deg']:.4f} deg, "
                  f"dz {r['dz_rmse_mm']:.4f} mm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
