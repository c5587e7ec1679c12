"""Sub-pixel bias of the corners' tracking: the LK alone, then rendered axial moves per codec.

Part 1 moves an analytic blurred corner (the product of two Gaussian-blurred steps,
sampled exactly at any shift) by sub-pixel amounts and runs
:func:`~camwhisker.vision.lk.refine_first_template` on it: the LK's own bias
against the shift, per blur. Part 2 renders each build's scene at rest and at
small axial moves (its own blur and noise), runs the front end (as
``calibrate-sensor`` tracks a sweep, with the build's true file, a 30-frame rest)
on the frames as they leave each codec, and prints the read dz and the
corners' error along their true projected move.

    camwhisker dev subpixel-bench [--seeds 5,210,211] [--levels 0.1,0.5]
"""

from __future__ import annotations

import argparse
import math
import warnings
from dataclasses import replace

import cv2
import numpy as np
from scipy.special import ndtr

from camwhisker.bench.seeds import seed_list
from camwhisker.calibration.sweep import SWEEP_APEX_MASK_PX, SWEEP_SQUARE_BAND_PX
from camwhisker.sensor.file import Sensor
from camwhisker.sensor.model import TIP, PlateModel
from camwhisker.sensor.plate import Pose
from camwhisker.sim.render.artefacts import Artefacts, apply_artefacts, illumination_field
from camwhisker.sim.render.builds import draw_build
from camwhisker.sim.render.render import SceneRenderer
from camwhisker.vision.lk import PATCH_HALF_PX, refine_first_template, warp_templates
from camwhisker.vision.stream import REST_FRAMES, Frame, stream
from camwhisker.vision.tracker import FrontEndOptions

__all__ = ["blurred_corner", "lk_bias_curve", "codec_rows", "CODECS", "main"]

#: Frames tracked at each level of part 2: their noise averages down to ~0.01 px.
FRAMES_PER_LEVEL = 8
#: The codecs of part 2: (chroma sampling, quality); None: the build's own quality.
CODECS = {
    "none": None,
    "JPEG 4:2:0": (cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420, None),
    "JPEG 4:4:4": (cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444, None),
    "JPEG 4:2:0 q95": (cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420, 95),
}


def blurred_corner(n: int, corner_uv, sigma_px: float) -> np.ndarray:
    """An n x n image of a corner at ``corner_uv`` (px): 1 where u > u0 and v > v0,
    blurred by a Gaussian of ``sigma_px``, each pixel its exact value at its centre."""
    r = np.arange(n, dtype=float)
    across = ndtr((r - corner_uv[0]) / sigma_px)
    down = ndtr((r - corner_uv[1]) / sigma_px)
    return (down[:, None] * across[None, :]).astype(np.float32)


def lk_bias_curve(shifts_px, direction, sigma_px: float, frac=(0.3, 0.7)) -> np.ndarray:
    """The LK's error (px, along ``direction``) after moving a blurred corner by each of
    ``shifts_px``; the rest corner lies ``frac`` off the pixel grid."""
    n = 2 * (PATCH_HALF_PX + 8) + 1
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    rest = np.array([n // 2 + frac[0], n // 2 + frac[1]])
    tmpl = warp_templates(blurred_corner(n, rest, sigma_px), np.zeros(2), rest[None],
                          np.eye(2)[None], PATCH_HALF_PX)  # fmt: skip
    out = []
    for s in np.asarray(shifts_px, float):
        moved = blurred_corner(n, rest + s * d, sigma_px)
        uv, _ = refine_first_template(moved, np.zeros(2), tmpl, rest[None], np.ones(1, bool))
        out.append((uv[0] - rest - s * d) @ d)
    return np.array(out)


def _encode(image: np.ndarray, codec, quality: int) -> np.ndarray:
    if codec is None:
        return image
    sampling, q = codec
    params = [cv2.IMWRITE_JPEG_QUALITY, int(q or quality), cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
              sampling]  # fmt: skip
    ok, buf = cv2.imencode(".jpg", image, params)
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return cv2.imdecode(buf, cv2.IMREAD_COLOR)


def codec_rows(seed: int, levels_mm) -> list[tuple[str, float, float, float, float]]:
    """Per codec and level: (codec, dz_mm, read dz_mm, the corners' mean and largest
    |error| along their move, px), build ``seed`` tracked with its true file."""
    build = draw_build(seed, Sensor())
    model = PlateModel(build.sensor)
    renderer = SceneRenderer(build.sensor, build.appearance)
    scenes = {dz: renderer.geometry(Pose(dz_mm=dz)) for dz in (0.0, *levels_mm)}
    webcam = build.webcam
    art = Artefacts(blur_sigma_px=webcam["blur_sigma_px"], noise_dn=webcam["noise_dn"])
    light = illumination_field(renderer.shape, art)
    options = replace(FrontEndOptions(), apex_mask_px=SWEEP_APEX_MASK_PX,
                      square_band_px=SWEEP_SQUARE_BAND_PX)  # fmt: skip
    uv0 = model.project(np.zeros(5), jacobian=False)[0]
    rows = []
    for name, codec in CODECS.items():
        rng = np.random.default_rng(seed)
        counts = [REST_FRAMES] + [FRAMES_PER_LEVEL] * len(levels_mm)
        poses = [dz for dz, k in zip((0.0, *levels_mm), counts, strict=True) for _ in range(k)]
        images = [_encode(apply_artefacts(scenes[dz], 0.0, art, rng, light), codec,
                          webcam["jpeg_quality"]) for dz in poses]  # fmt: skip
        frames = (Frame(i, i / 30.0, im) for i, im in enumerate(images))
        results = [r for _, r in stream(frames, build.sensor, options)]
        pts = np.array([r.points_uv[:TIP] for r in results])
        rest = pts[:REST_FRAMES].mean(axis=0)
        for j, dz in enumerate(levels_mm):
            at = slice(REST_FRAMES + j * FRAMES_PER_LEVEL, REST_FRAMES + (j + 1) * FRAMES_PER_LEVEL)
            move = (model.project(np.array([dz, 0, 0, 0, 0.0]), jacobian=False)[0] - uv0)[:TIP]
            unit = move / np.linalg.norm(move, axis=1, keepdims=True)
            with warnings.catch_warnings():  # a corner the LK lost in every frame: NaN
                warnings.simplefilter("ignore", RuntimeWarning)
                along = np.sum((np.nanmean(pts[at], axis=0) - rest - move) * unit, axis=1)
            read = float(np.nanmean([r.dz_mm for r in results[at]]))
            rows.append((name, dz, read, float(np.nanmean(along)), float(np.nanmax(np.abs(along)))))
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="camwhisker dev subpixel-bench", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--seeds", type=seed_list, default="5,210,211", help="builds of part 2")
    p.add_argument("--levels", default="0.1,0.5", help="axial moves of part 2 (mm)")
    args = p.parse_args(argv)
    try:
        levels = [float(x) for x in args.levels.split(",")]
    except ValueError:
        p.error(f"--levels must be numbers separated by commas, got {args.levels!r}")
    if not all(0 < x <= 1.5 and math.isfinite(x) for x in levels):
        p.error(f"--levels must lie in (0, 1.5] mm, got {args.levels!r}")
    shifts = np.round(np.arange(0.0, 1.01, 0.1), 2)
    print("LK error (px) of an analytic corner moved diagonally, rest 0.3, 0.7 px off the grid")
    print("| blur sigma (px) | " + " | ".join(f"{s:g}" for s in shifts) + " |")
    print("|---|" + "---|" * len(shifts))
    for sigma in (0.7, 1.0, 1.8, 2.6):
        bias = lk_bias_curve(shifts, (0.6, 0.8), sigma)
        print(f"| {sigma:g} | " + " | ".join(f"{b:+.4f}" for b in bias) + " |")
    print("\nRendered axial moves, the build's true file: read dz, corners' error along the move")
    print("| build | codec | dz (mm) | read dz (mm) | error mean (px) | largest (px) |")
    print("|---|---|---|---|---|---|")
    for seed in args.seeds:
        for name, dz, read, mean, worst in codec_rows(seed, levels):
            print(f"| {seed} | {name} | {dz:g} | {read:+.4f} | {mean:+.3f} | {worst:.3f} |",
                  flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
