"""Where a calibration's error comes from: the front end's tracking errors on the sweep.

For each build of the reality suite: render its calibration sweep and a separate
clip (as :mod:`camwhisker.bench.calibration` does), calibrate, and compare the
last round's tracked points with where the build's true geometry and the
scene's true poses put them. A tracked corner is the plate point its rest
template is centred on, off the true corner by a constant in the plate
(:mod:`camwhisker.calibration.adjust`): its true place carries its offset at rest
as an in-plane shift. Per build and source of error (the tracked points of the
square's corners, of the cross's, of the tip, or all of them; the rod's diameter,
which the calibration measures apart), it prints:

- the tracking error's tilt-dependent part: the RMS over the group's coordinates
  of the coefficients of ``adjust.SYSTEMATIC_PX``'s terms (a/PHI0, b/PHI0,
  phi^2/PHI0^2), fitted with dz and a constant, and the scatter left about them;
- the clip's phi and dz RMSE, fitted file over true file, when the last round is
  adjusted again with that source taken out: the points replaced by their true
  places plus white noise of each point's own (:func:`white_noise_px`), the rod's
  diameter held at the truth. "as tracked" is the calibration itself; "all points,
  rod" is what the white noise alone leaves. The sources interact (the fit trades
  one's error against another's), so the rows do not add up. The noise is drawn
  ``--draws`` times: the mean ratio, and the smallest and largest.

    camwhisker dev systematics-bench --seeds 169,179 [--draws 3] [--sweep-s 20] [--cache DIR]
"""

from __future__ import annotations

import argparse
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camwhisker.bench.calibration import (
    CLIP_SEED_OFFSET,
    add_sweep_arguments,
    sweep_frames_of,
)
from camwhisker.bench.reality import clip_row, render_build_clip
from camwhisker.bench.seeds import seed_list
from camwhisker.calibration.adjust import bias_terms, corner_shift_jacobian
from camwhisker.calibration.sweep import (
    ROD_DIAMETER,
    SQUARE_SIDE,
    SensorFit,
    adjust_tracked,
    calibrate_sensor,
)
from camwhisker.io.sources import VideoSource
from camwhisker.sensor.file import Sensor
from camwhisker.sensor.model import TIP, PlateModel
from camwhisker.sim.render.builds import draw_build
from camwhisker.sim.render.scenarios import PoseTrack

__all__ = ["GROUPS", "GroupRow", "true_poses", "true_tracked_points", "tilt_coefficients",
           "white_noise_px", "refit_with_true_points", "run_build", "main"]  # fmt: skip

#: The sources of error taken out in turn: the tracked points replaced (indices into the
#: 13: 12 corners, then the tip), and whether the rod's diameter is held at the truth.
GROUPS = {"square": ((0, 1, 2, 3), False), "cross": (tuple(range(4, TIP)), False),
          "tip": ((TIP,), False), "rod": ((), True), "all points": (tuple(range(TIP + 1)), False),
          "all points, rod": (tuple(range(TIP + 1)), True)}  # fmt: skip


@dataclass(frozen=True)
class GroupRow:
    """One source of error taken out, on one build."""

    seed: int
    group: str
    tilt_px: float  # RMS tilt-term coefficient over the group's coordinates (px)
    scatter_px: float  # RMS residual about the fitted terms (px)
    phi_ratio: float  # clip phi RMSE, the file refitted without the source / the true file
    dz_ratio: float
    phi_ratio_range: tuple[float, float] = (math.nan, math.nan)  # over the noise's draws


def true_poses(track: PoseTrack) -> np.ndarray:
    """The pose vectors (dz, a, b, sx, sy) of a truth track, shape (F, 5); at rest
    (theta undefined) a = b = 0."""
    phi = np.radians(track.phi_deg)
    theta = np.nan_to_num(np.radians(track.theta_deg))
    return np.column_stack([track.dz_mm, phi * np.cos(theta), phi * np.sin(theta),
                            track.sx_mm, track.sy_mm])  # fmt: skip


def true_tracked_points(sensor: Sensor, q: np.ndarray, tracked_uv: np.ndarray,
                        rest: np.ndarray) -> np.ndarray:  # fmt: skip
    """Where the true geometry ``sensor`` puts each tracked point at the true poses ``q``,
    shape (F, 13, 2): a corner carries its offset at rest (median over the ``rest``
    frames of tracked minus model) as an in-plane shift in the plate, the tip as a
    constant in the image."""
    model = PlateModel(sensor)
    true = np.array([model.project(qq, jacobian=False)[0] for qq in q])
    offset = np.nanmedian(tracked_uv[rest] - true[rest], axis=0)
    shift = np.linalg.solve(corner_shift_jacobian(model, np.zeros(5)), offset[:TIP, :, None])
    for f, qq in enumerate(q):
        true[f, :TIP] += (corner_shift_jacobian(model, qq) @ shift)[..., 0]
    true[:, TIP] += offset[TIP]
    return true


def tilt_coefficients(error_uv: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each point's and coordinate's error regressed on the tilt terms of
    :func:`~camwhisker.calibration.adjust.bias_terms`, dz and a constant, over its finite
    frames: the terms' coefficients (13, 2, 3) and the residual's RMS (13, 2), px."""
    terms = np.array([bias_terms(qq[:3]) for qq in q])
    design = np.column_stack([terms, q[:, 0], np.ones(len(q))])
    coef = np.full((*error_uv.shape[1:], 3), np.nan)
    scatter = np.full(error_uv.shape[1:], np.nan)
    for i, c in np.ndindex(*error_uv.shape[1:]):
        y = error_uv[:, i, c]
        use = np.isfinite(y)
        if use.sum() <= design.shape[1]:
            continue
        fit, *_ = np.linalg.lstsq(design[use], y[use], rcond=None)
        coef[i, c] = fit[:3]
        scatter[i, c] = np.sqrt(np.mean((y[use] - design[use] @ fit) ** 2))
    return coef, scatter


def white_noise_px(error_uv: np.ndarray) -> np.ndarray:
    """Each point's white error SD per coordinate, shape (13,): the RMS of its error's
    change from one frame to the next over sqrt(2) (what drifts with the pose cancels)."""
    step = np.diff(error_uv, axis=0)
    return np.sqrt(np.nanmean(step**2, axis=(0, 2)) / 2.0)


def refit_with_true_points(cal: SensorFit, nominal: Sensor, true_uv: np.ndarray,
                           points: tuple[int, ...], noise_px: np.ndarray, seed: int = 0,
                           rod_diameter_mm: float | None = None) -> Sensor:  # fmt: skip
    """The calibration's last round adjusted again, the tracked ``points`` replaced by
    ``true_uv`` plus Gaussian noise of SD ``noise_px`` (13,) where they were tracked;
    the square's side and the rod's diameter held at the calibration's, or the rod's
    at ``rod_diameter_mm``."""
    tracked = cal.tracked
    pts = np.where((tracked.ok | tracked.rest)[:, None, None], tracked.points_uv, np.nan)
    noise = np.random.default_rng(seed).normal(size=pts.shape) * noise_px[:, None]
    idx = list(points)
    pts[:, idx] = np.where(np.isfinite(pts[:, idx]), true_uv[:, idx] + noise[:, idx], np.nan)
    plate = cal.sensor.plate
    rod = plate.rod_diameter_mm if rod_diameter_mm is None else rod_diameter_mm
    fixed = {SQUARE_SIDE: plate.square_side_mm, ROD_DIAMETER: rod}
    start = nominal.replace(plate={"square_side_mm": plate.square_side_mm})
    return adjust_tracked(tracked, pts, start, fixed).sensor


def run_build(seed: int, sweep_frames: int, clip_frames: int, folder: Path,
              draws: int = 3) -> list[GroupRow]:  # fmt: skip
    """Calibrate build ``seed`` on its sweep; one row per source, and "as tracked"."""
    nominal = Sensor()
    build = draw_build(seed, nominal)
    sweep_scene, sweep = render_build_clip(build, "calibration_sweep", sweep_frames, seed, folder)
    clip_scene, clip = render_build_clip(build, "nominal", clip_frames, seed + CLIP_SEED_OFFSET,
                                         folder)  # fmt: skip
    cal = calibrate_sensor([sweep], nominal, build.sensor.plate.square_side_mm)
    q = true_poses(sweep_scene.track)
    tracked = cal.tracked
    true_uv = true_tracked_points(build.sensor, q, tracked.points_uv, tracked.rest)
    trusted = (tracked.ok & ~tracked.rest)[:, None, None]
    error = np.where(trusted, tracked.points_uv - true_uv, np.nan)
    coef, scatter = tilt_coefficients(error, q)
    noise_px = white_noise_px(error)
    frames = [f.image for f in VideoSource(clip)]
    true_row = clip_row(seed, "true", frames, clip_scene, build.sensor)

    def ratios(sensor: Sensor) -> tuple[float, float]:
        r = clip_row(seed, "fitted", frames, clip_scene, sensor)
        return r.phi_rmse_deg / true_row.phi_rmse_deg, r.dz_rmse_mm / true_row.dz_rmse_mm

    rows = [GroupRow(seed, "as tracked", math.nan, math.nan, *ratios(cal.sensor))]
    true_rod = build.sensor.plate.rod_diameter_mm
    for name, (points, rod) in GROUPS.items():
        idx = list(points)
        tilt, left = (float(np.sqrt(np.nanmean(a[idx] ** 2))) if idx else math.nan
                      for a in (coef, scatter))  # fmt: skip
        held = true_rod if rod else None
        phi, dz = np.array([ratios(refit_with_true_points(cal, nominal, true_uv, points,
                                                          noise_px, draw, held))
                            for draw in range(draws if idx else 1)]).T  # fmt: skip
        rows.append(GroupRow(seed, name, tilt, left, float(phi.mean()), float(dz.mean()),
                             (float(phi.min()), float(phi.max()))))  # fmt: skip
    return rows


def table(rows: list[GroupRow]) -> str:
    """One Markdown row per build and source."""
    lines = ["| build | taken out | tilt terms RMS (px) | scatter (px) | phi fitted/true "
             "(range over draws) | dz fitted/true |", "|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        lo, hi = r.phi_ratio_range
        spread = "" if math.isnan(lo) or lo == hi else f"({lo:.2f}-{hi:.2f})"
        lines.append(f"| {r.seed} | {r.group} | {r.tilt_px:.3f} | {r.scatter_px:.3f} | "
                     f"{r.phi_ratio:.2f} {spread} | {r.dz_ratio:.2f} |")  # fmt: skip
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="camwhisker dev systematics-bench", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--seeds", type=seed_list, required=True, help="e.g. 169,179 or 0-4")
    p.add_argument("--draws", type=int, default=3, help="draws of the true points' noise")
    add_sweep_arguments(p, sweep_s=20.0)
    args = p.parse_args(argv)
    sweep_frames = sweep_frames_of(p, args)
    if args.draws < 1:
        p.error(f"--draws must be at least 1, got {args.draws}")
    rows = []
    with tempfile.TemporaryDirectory(prefix="camwhisker-sysbench-") as tmp:
        folder = Path(args.cache or tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for seed in args.seeds:
            rows += run_build(seed, sweep_frames, args.clip_frames, folder,
                              args.draws)  # fmt: skip
            print(table(rows[-len(GROUPS) - 1:]), flush=True)
    print()
    print(table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
