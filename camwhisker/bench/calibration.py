"""Calibration benchmark: ``calibrate-sensor`` on held-out builds of the reality suite.

For each build: render a calibration sweep of the build and a separate clip
of the nominal scene (another render seed), fit the build's sensor file to
the sweep from the nominal file and the true square side, then run the front
end on the clip with the nominal, the fitted and the true file. Prints one
Markdown row per build (rows ok, phi and dz RMSE per file, fitted/true
ratios, the share of fitted parameters within 3 SE of the truth, the fitted
geometry's phi error at 20 deg against the report's SE, the calibration's
seconds) and a summary against the acceptance limits.

With ``--dz-steps`` each build also films the paper's test 2 (0.1 mm axial steps
to 1 mm, scene ``dz_steps``, another render seed) with its stage log, recorded
without compression (H.264 at CRF 0; ``--steps-mjpg``: the webcam's MJPG, whose
quantisation moves each corner by 0.1-0.5 px at such small moves,
``camwhisker dev subpixel-bench``), and the calibration gets it; the row then also
gives the fitted file's dz gain error (linearised at CHECK_DZ_MM, against the
build's true geometry) and the report's SE of dz's scale, and the limits are the
steps' (dz within MAX_RATIO_STEPS, gain within MAX_GAIN_ERROR).

    camwhisker dev calibration-bench [--seeds 100-104] [--sweep-s 12] [--clip-frames 120]
                                     [--dz-steps [--steps-mjpg]]
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camwhisker.bench.reality import RealityRow, clip_row, render_build_clip
from camwhisker.bench.seeds import seed_list
from camwhisker.calibration.sweep import calibrate_sensor
from camwhisker.contact.stage import StageLog, stage_log_from_arrays
from camwhisker.io.sources import VideoSource
from camwhisker.sensor.file import Sensor
from camwhisker.sensor.model import GEOMETRY_NAMES, PlateModel, geometry_vector
from camwhisker.sim.render.builds import REALITY_SUITE, draw_build
from camwhisker.sim.render.scenarios import dz_steps_frames
from camwhisker.vision.detect import FeaturesNotFound
from camwhisker.vision.mismatch import CHECK_PHI_DEG, dz_gain_response, phi_error_deg

__all__ = ["CalibrationRow", "render_steps", "run_build", "table", "summary", "add_sweep_arguments",
           "sweep_frames_of", "main"]

FPS = 30.0
#: The clip's render seed is the build's plus this: its poses and noise differ from the sweep's.
CLIP_SEED_OFFSET = 1000
#: ... and the dz steps' video's.
STEPS_SEED_OFFSET = 2000
#: Acceptance limits: fitted/true RMSE ratio, share of ok rows, share within 3 SE.
MAX_RATIO = 1.5
MIN_OK = 0.99
MIN_WITHIN_3SE = 0.95
#: With known dz steps: fitted/true dz RMSE, and |dz's gain - 1| of the fitted file.
MAX_RATIO_STEPS = 1.2
MAX_GAIN_ERROR = 0.003


@dataclass(frozen=True)
class CalibrationRow:
    """One build: the clip with each file, and the fit against the truth."""

    seed: int
    nominal: RealityRow
    fitted: RealityRow | None
    true: RealityRow
    within_3se: float  # share of fitted (not held) parameters within 3 SE of the truth
    n_fitted: int
    calibration_s: float
    note: str = ""
    outside: tuple[str, ...] = ()  # fitted parameters more than 3 SE off the truth
    #: phi's SE at CHECK_PHI_DEG as the report gives it, and the fitted geometry's phi
    #: error there (linearised, worst of CHECK_THETA_DEG) (deg).
    phi_se_deg: float = math.nan
    phi_error_deg: float = math.nan
    #: The fitted file's dz gain less one (linearised, against the truth), the report's
    #: relative SE of it, and whether known dz steps were given.
    gain_error: float = math.nan
    gain_se: float = math.nan
    dz_steps: bool = False

    def ratio(self, attr: str) -> float:
        """Fitted over true of ``attr`` (a :class:`RealityRow` field); NaN without a fit."""
        if self.fitted is None:
            return math.nan
        return getattr(self.fitted, attr) / getattr(self.true, attr)

    def meets(self) -> dict[str, bool]:
        """Each acceptance limit met or not."""
        out = {
            "phi": self.ratio("phi_rmse_deg") <= MAX_RATIO,
            "dz": self.ratio("dz_rmse_mm") <= (MAX_RATIO_STEPS if self.dz_steps else MAX_RATIO),
            "ok": self.fitted is not None and self.fitted.ok >= MIN_OK,
            "se": self.within_3se >= MIN_WITHIN_3SE,
        }
        if self.dz_steps:
            out["gain"] = abs(self.gain_error) <= MAX_GAIN_ERROR
        return out


def within_3se(value: np.ndarray, se: np.ndarray, truth: np.ndarray) -> tuple[float, int]:
    """Share of the fitted parameters (finite SE) within 3 SE of the truth, and their count."""
    fitted = np.isfinite(se)
    if not fitted.any():
        return math.nan, 0
    inside = np.abs(value[fitted] - truth[fitted]) <= 3.0 * se[fitted]
    return float(inside.mean()), int(fitted.sum())


def outside_3se(value: np.ndarray, se: np.ndarray, truth: np.ndarray) -> tuple[str, ...]:
    """Names of the fitted parameters more than 3 SE off the truth."""
    with np.errstate(invalid="ignore"):
        off = np.isfinite(se) & (np.abs(value - truth) > 3.0 * se)
    return tuple(n for n, o in zip(GEOMETRY_NAMES, off, strict=True) if o)


def render_steps(build, seed: int, folder: Path, lossless: bool = True) -> tuple[Path, StageLog]:
    """Build ``seed``'s video of known dz steps (``lossless``: uncompressed, else the
    webcam's MJPG) and its stage log (the scene's exact dz)."""
    scenario, video = render_build_clip(build, "dz_steps", dz_steps_frames(FPS),
                                        seed + STEPS_SEED_OFFSET, folder, lossless)  # fmt: skip
    track = scenario.track
    log = stage_log_from_arrays(track.t_s, track.dz_mm, source=f"{video.stem}.stage.csv",
                                dz_mm=track.dz_mm)  # fmt: skip
    return video, log


def run_build(seed: int, sweep_frames: int, clip_frames: int, folder: Path,
              nominal: Sensor | None = None, dz_steps: bool = False,
              steps_lossless: bool = True) -> CalibrationRow:  # fmt: skip
    """Calibrate build ``seed`` on its sweep (and its dz steps, ``steps_lossless`` or
    MJPG) and score the three files on a separate clip."""
    nominal = nominal or Sensor()
    build = draw_build(seed, nominal)
    _, sweep = render_build_clip(build, "calibration_sweep", sweep_frames, seed, folder)
    scenario, clip = render_build_clip(build, "nominal", clip_frames, seed + CLIP_SEED_OFFSET,
                                       folder)  # fmt: skip
    steps = [render_steps(build, seed, folder, steps_lossless)] if dz_steps else []
    t0 = time.perf_counter()
    try:
        cal = calibrate_sensor([sweep], nominal, build.sensor.plate.square_side_mm,
                               dz_steps=steps)  # fmt: skip
    except (FeaturesNotFound, ValueError) as exc:
        cal, note = None, f"calibration failed: {exc}"
    seconds = time.perf_counter() - t0
    frames = [f.image for f in VideoSource(clip)]
    rows = {label: clip_row(seed, label, frames, scenario, sensor)
            for label, sensor in (("nominal", nominal), ("true", build.sensor))}  # fmt: skip
    if cal is None:
        return CalibrationRow(seed, rows["nominal"], None, rows["true"], math.nan, 0, seconds,
                              note, dz_steps=dz_steps)  # fmt: skip
    adj = cal.adjustment
    truth = geometry_vector(build.sensor)
    share, n_fitted = within_3se(adj.value, adj.se, truth)
    fitted = clip_row(seed, "fitted", frames, scenario, cal.sensor)
    phi_error = phi_error_deg(PlateModel(cal.sensor), adj.value - truth)
    gain_error = float(dz_gain_response(PlateModel(build.sensor)) @ (adj.value - truth))
    return CalibrationRow(seed, rows["nominal"], fitted, rows["true"], share, n_fitted, seconds,
                          "; ".join(r.note for r in (fitted, rows["true"]) if r.note),
                          outside_3se(adj.value, adj.se, truth), adj.phi_se_deg(),
                          phi_error, gain_error, adj.dz_scale.se, dz_steps)  # fmt: skip


def _cells(r: RealityRow | None) -> list[str]:
    if r is None:
        return ["-", "-", "-"]
    return [f"{100 * r.ok:.1f}%", f"{r.phi_rmse_deg:.4f}", f"{r.dz_rmse_mm:.4f}"]


def _gain_cell(r: CalibrationRow) -> str:
    if not math.isfinite(r.gain_error):
        return "-"
    return f"{100 * r.gain_error:+.2f} / {100 * r.gain_se:.2f}"


def table(rows: list[CalibrationRow]) -> str:
    """One Markdown row per build."""
    head = ["build"]
    for label in ("nominal", "fitted", "true"):
        head += [f"ok {label}", f"phi RMSE {label} (deg)", f"dz RMSE {label} (mm)"]
    head += ["phi fitted/true", "dz fitted/true", "within 3 SE", "phi error / SE at 20 deg",
             "dz gain error / SE (%)", "calibration (s)", "note"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [str(r.seed), *_cells(r.nominal), *_cells(r.fitted), *_cells(r.true),
                 f"{r.ratio('phi_rmse_deg'):.2f}", f"{r.ratio('dz_rmse_mm'):.2f}",
                 f"{100 * r.within_3se:.0f}% of {r.n_fitted}",
                 f"{r.phi_error_deg:.4f} / {r.phi_se_deg:.4f}",
                 _gain_cell(r), f"{r.calibration_s:.0f}",
                 r.note]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def summary(rows: list[CalibrationRow]) -> str:
    """How many builds meet each acceptance limit, and all of them."""
    meets = [r.meets() for r in rows]
    n = len(rows)
    count = {k: sum(m.get(k, False) for m in meets) for k in ("phi", "dz", "ok", "se", "gain")}
    dz_limit = MAX_RATIO_STEPS if any(r.dz_steps for r in rows) else MAX_RATIO
    detected = sum(r.true.detected and r.nominal.detected for r in rows)
    fits = [r for r in rows if r.n_fitted]
    n_par = sum(r.n_fitted for r in fits)
    n_in = sum(round(r.within_3se * r.n_fitted) for r in fits)
    off = Counter(name for r in fits for name in r.outside)
    worst = ", ".join(f"{name} {k}" for name, k in off.most_common()) or "none"
    covered = sum(r.phi_error_deg <= 3 * r.phi_se_deg for r in fits)
    gains = sum(abs(r.gain_error) <= 3 * r.gain_se for r in fits)
    steps = (f", dz gain within {100 * MAX_GAIN_ERROR:g} % {count['gain']}/{n}"
             if any(r.dz_steps for r in rows) else "")
    return (f"{n} builds: detected {detected}/{n}; phi within {MAX_RATIO}x {count['phi']}/{n}, "
            f"dz within {dz_limit}x {count['dz']}/{n}, >= {100 * MIN_OK:.0f} % ok "
            f"{count['ok']}/{n}, >= {100 * MIN_WITHIN_3SE:.0f} % within 3 SE {count['se']}/{n}"
            f"{steps}; all {sum(all(m.values()) for m in meets)}/{n}\n"
            f"dz gain error within 3 reported SE: {gains}/{len(fits)}\n"
            f"fitted parameters within 3 SE, builds pooled: {n_in}/{n_par}; "
            f"builds where each is outside: {worst}\n"
            f"phi error at {CHECK_PHI_DEG:g} deg within 3 reported SE: "
            f"{covered}/{len(fits)}")  # fmt: skip


def add_sweep_arguments(p: argparse.ArgumentParser, sweep_s: float) -> None:
    """The sweep's and clip's options of the benches that calibrate rendered builds."""
    p.add_argument("--sweep-s", type=float, default=sweep_s, help="sweep length (s, at most 20)")
    p.add_argument("--clip-frames", type=int, default=120, help="frames of the separate clip")
    p.add_argument("--cache", metavar="DIR", help="folder for the renders, reused on a rerun")


def sweep_frames_of(p: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    """The sweep's frames from ``--sweep-s``; a sweep lasts at most 20 s, as a user's would."""
    if not 0 < args.sweep_s <= 20:
        p.error(f"--sweep-s must be in (0, 20], got {args.sweep_s}")
    return round(args.sweep_s * FPS)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="camwhisker dev calibration-bench", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    held = REALITY_SUITE.held_out_seeds
    p.add_argument("--seeds", type=seed_list, default=f"{held[0]}-{held[4]}",
                   help="e.g. 100-104, 100,107 or 100-104,107")  # fmt: skip
    add_sweep_arguments(p, sweep_s=12.0)
    p.add_argument("--dz-steps", action="store_true",
                   help="calibrate with a video of known dz steps too (the paper's test 2)")
    p.add_argument("--steps-mjpg", action="store_true",
                   help="the steps' video in the webcam's MJPG, not uncompressed")
    args = p.parse_args(argv)
    sweep_frames = sweep_frames_of(p, args)
    rows = []
    with tempfile.TemporaryDirectory(prefix="camwhisker-calbench-") as tmp:
        folder = Path(args.cache or tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for seed in args.seeds:
            rows.append(run_build(seed, sweep_frames, args.clip_frames, folder,
                                  dz_steps=args.dz_steps,
                                  steps_lossless=not args.steps_mjpg))  # fmt: skip
            print(table(rows[-1:]).splitlines()[-1], flush=True)
    print()
    print(table(rows))
    print(f"\n{summary(rows)}")
    codec = "MJPG" if args.steps_mjpg else "uncompressed"
    steps = f", with dz steps (scene dz_steps, {codec})" if args.dz_steps else ""
    print(f"sweep {args.sweep_s:g} s ({sweep_frames} frames){steps}, clip 'nominal' "
          f"{args.clip_frames} frames (MJPG), seeds {','.join(map(str, args.seeds))}; "
          f"tune only on seeds {REALITY_SUITE.tuning_seeds}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
