"""Calibrate a build from its sweep videos: track, adjust, track again with the fit.

The front end tracks the sweep with the current sensor estimate; its image
points (:attr:`FrameResult.points_uv`) go to the bundle adjustment
(:mod:`camwhisker.geometry.adjust`), and the fitted file tracks the sweep
again: with the nominal file a real build loses frames, with a fitted one it
does not. Rounds stop when the fit no longer moves by more than a fraction
of its standard errors.

Each video starts at rest: its first frame is the front end's rest frame, and
the frames before the plate first moves are held at pose zero. The square's
side, measured with calipers, fixes the scale. The rod's diameter is measured
from the tip's radius at rest (the adjustment cannot see it, the front end's
tip measurement can). Intrinsics from chessboard
images (:func:`intrinsics_from_chessboard`) may be given; they are then held.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from camwhisker.camera import INTRINSIC_NAMES
from camwhisker.geometry.adjust import Adjustment, adjust_geometry
from camwhisker.model import TIP, PlateModel
from camwhisker.polygon import polygon_centroid
from camwhisker.sensor import Sensor
from camwhisker.sources import open_source
from camwhisker.stream import track
from camwhisker.vision.tip import ellipse_centre, tip_edge_points
from camwhisker.vision.tracker import TIP_SEARCH_PX, FrontEnd, FrontEndOptions

__all__ = [
    "REST_PX",
    "MAX_ROUNDS",
    "TrackedSweep",
    "Calibration",
    "track_sweep",
    "rest_frames",
    "rest_tip_radius_px",
    "rod_diameter_mm",
    "calibrate_sensor",
    "intrinsics_from_chessboard",
]

#: A leading frame is at rest while its points stay this close to the first
#: frame's (median over the points, px): a few times the tracking noise.
REST_PX = 0.3
#: Rounds of tracking and adjustment at most.
MAX_ROUNDS = 3
#: The fit is stable when no parameter moved by more than this many SE in a round.
STABLE_SE = 0.5
SQUARE_SIDE = "plate.square_side_mm"
ROD_DIAMETER = "plate.rod_diameter_mm"


@dataclass(frozen=True)
class TrackedSweep:
    """The front end's output over the sweep's videos, frames concatenated.

    points_uv : ndarray, shape (F, 13, 2); NaN where not tracked
    q : ndarray, shape (F, 5); the front end's poses (zero where untrusted)
    ok : ndarray of bool, shape (F,)
    rest : ndarray of bool, shape (F,); the leading frames at rest of each video
    video : ndarray of int, shape (F,); which video each frame came from
    """

    points_uv: np.ndarray
    q: np.ndarray
    ok: np.ndarray
    rest: np.ndarray
    video: np.ndarray


@dataclass(frozen=True)
class Calibration:
    """The calibrated geometry and how it was reached.

    adjustment : the last round's :class:`Adjustment`
    tracked : the last round's :class:`TrackedSweep` (tracked with the previous fit)
    ok_fraction : the fraction of ok rows in each round's tracking
    """

    adjustment: Adjustment
    tracked: TrackedSweep
    ok_fraction: list = field(default_factory=list)
    #: The tip's radius at rest (px), mean over the videos: it gives the rod's diameter.
    tip_radius_px: float = float("nan")

    @property
    def sensor(self) -> Sensor:
        return self.adjustment.sensor


def rest_frames(points_uv: np.ndarray) -> np.ndarray:
    """The leading run of frames whose points stay within ``REST_PX`` of frame 0's."""
    d = np.linalg.norm(points_uv - points_uv[0], axis=-1)
    with np.errstate(all="ignore"):
        still = np.nanmedian(d, axis=1) <= REST_PX
    run = int(np.argmin(still)) if not still.all() else len(still)
    out = np.zeros(len(points_uv), dtype=bool)
    out[: max(run, 1)] = True
    return out


def rest_tip_radius_px(video: str | Path, sensor: Sensor,
                       options: FrontEndOptions | None = None) -> float:  # fmt: skip
    """The end face's mean radius (px) in the video's first frame, from an ellipse
    fitted to its whole edge: at rest the rod hides none of it.

    Raises
    ------
    camwhisker.vision.FeaturesNotFound
        The first frame lacks a feature.
    """
    image = next(iter(open_source(video))).image
    fe = FrontEnd(sensor, options)
    fe.start(image)
    edges, _, why = tip_edge_points(image, fe.rest.gains, fe.rest.uv[TIP],
                                    _rim_radius_px(sensor), TIP_SEARCH_PX)  # fmt: skip
    tip = ellipse_centre(edges) if edges is not None else None
    if tip is None or not tip.ok:
        raise ValueError(f"{video}: the tip's edge at rest: {why or tip.reason}")
    return float(tip.radius_px)


def _rim_radius_px(sensor: Sensor) -> float:
    """The model's end-face rim at rest: its mean radius about its centroid (px)."""
    rim = PlateModel(sensor).outlines(np.zeros(5))[0]
    return float(np.mean(np.linalg.norm(rim - polygon_centroid(rim), axis=1)))


def rod_diameter_mm(sensor: Sensor, tip_radius_px: float) -> float:
    """The rod's diameter that makes the model's rim at rest as large as measured:
    the tip's measurement fits the model's rim to a partial edge, so its size matters."""
    return sensor.plate.rod_diameter_mm * tip_radius_px / _rim_radius_px(sensor)


def _q_from_results(results) -> np.ndarray:
    q = np.zeros((len(results), 5))
    for i, r in enumerate(results):
        phi = np.radians(r.phi_deg) if np.isfinite(r.phi_deg) else 0.0
        theta = np.radians(r.theta_deg) if np.isfinite(r.theta_deg) else 0.0
        dz = r.dz_mm if np.isfinite(r.dz_mm) else 0.0
        q[i, :3] = dz, phi * np.cos(theta), phi * np.sin(theta)
    return q


def track_sweep(
    videos: Sequence[str | Path],
    sensor: Sensor,
    on_frame: Callable[[], None] | None = None,
    options: FrontEndOptions | None = None,
) -> TrackedSweep:
    """Track every video of the sweep with ``sensor`` (and ``options``, such as the
    user's rough feature positions); ``on_frame`` is called per frame.

    Raises
    ------
    camwhisker.vision.FeaturesNotFound
        A video's first frame lacks a feature.
    """
    parts = []
    for k, video in enumerate(videos):
        images = (f.image for f in open_source(video))
        results = []
        for r in track(images, sensor, options):
            results.append(r)
            if on_frame is not None:
                on_frame()
        if not results:
            raise ValueError(f"{video}: no frames")
        pts = np.array([r.points_uv for r in results], dtype=float).reshape(-1, TIP + 1, 2)
        parts.append((pts, _q_from_results(results), np.array([r.ok for r in results]),
                      rest_frames(pts), np.full(len(results), k)))  # fmt: skip
    return TrackedSweep(*(np.concatenate(c) for c in zip(*parts, strict=True)))


def calibrate_sensor(
    videos: Sequence[str | Path],
    sensor: Sensor,
    square_side_mm: float,
    intrinsics: dict | None = None,
    rounds: int = MAX_ROUNDS,
    on_frame: Callable[[], None] | None = None,
    on_round: Callable[[int, Adjustment], None] | None = None,
    options: FrontEndOptions | None = None,
) -> Calibration:
    """Fit a build's geometry to its sweep videos, starting from the nominal ``sensor``.

    Parameters
    ----------
    videos : sequence of path
        Sweep videos, each starting at rest.
    sensor : Sensor
        The nominal sensor file.
    square_side_mm : float
        The square's side measured with calipers: fixes the scale.
    intrinsics : dict, optional
        ``[camera]`` keys (fx_px, fy_px, cx_px, cy_px, distortion) from a separate
        calibration: held at these values.
    rounds : int
        Rounds of tracking and adjustment at most.
    on_frame, on_round : callable, optional
        Progress: called per tracked frame, and after each round with its index and fit.
    options : FrontEndOptions, optional
        How the front end tracks the sweep (``features``: rough rest positions).

    Returns
    -------
    Calibration
    """
    if not square_side_mm > 0:
        raise ValueError(f"square_side_mm must be positive, got {square_side_mm}")
    if rounds < 1:
        raise ValueError(f"rounds must be >= 1, got {rounds}")
    start = sensor.replace(plate={"square_side_mm": float(square_side_mm)})
    fixed = {SQUARE_SIDE: float(square_side_mm)}
    if intrinsics:
        start = start.replace(camera=intrinsics)
        cam = start.camera
        values = [cam.fx_px, cam.fy_px, cam.cx_px, cam.cy_px, *cam.distortion]
        fixed.update({f"camera.{n}": v for n, v in zip(INTRINSIC_NAMES, values, strict=True)})
    radius_px = float(np.mean([rest_tip_radius_px(v, start, options) for v in videos]))
    current, previous, ok_fraction = start, None, []
    for k in range(rounds):
        fixed[ROD_DIAMETER] = rod_diameter_mm(current, radius_px)
        current = current.replace(plate={"rod_diameter_mm": fixed[ROD_DIAMETER]})
        tracked = track_sweep(videos, current, on_frame, options)
        ok_fraction.append(float(tracked.ok.mean()))
        # Only the rows the front end trusted: a lost track's points are no measurement.
        pts = np.where((tracked.ok | tracked.rest)[:, None, None], tracked.points_uv, np.nan)
        adj = adjust_geometry(pts, start, tracked.rest, fixed, tracked.q, corner_shifts=True)
        if on_round is not None:
            on_round(k, adj)
        current = adj.sensor
        if previous is not None and _stable(previous, adj):
            break
        previous = adj
    return Calibration(adj, tracked, ok_fraction, radius_px)


def _stable(before: Adjustment, after: Adjustment) -> bool:
    """No fitted parameter moved by more than ``STABLE_SE`` of its SE, none changed hold."""
    if set(before.held) != set(after.held):
        return False
    free = np.isfinite(after.se)
    return bool(np.all(np.abs(after.value - before.value)[free] <= STABLE_SE * after.se[free]))


def intrinsics_from_chessboard(
    images: Sequence[str | Path], pattern: tuple[int, int], square_mm: float,
    size: tuple[int, int] | None = None,
) -> tuple[dict, float]:  # fmt: skip
    """Camera intrinsics from chessboard images (OpenCV's calibrateCamera).

    Parameters
    ----------
    images : sequence of path
        Images of a flat chessboard in several orientations.
    pattern : (int, int)
        Inner corners per row and column, e.g. (9, 6).
    square_mm : float
        The board's square size (any unit: it does not enter the intrinsics).
    size : (width_px, height_px), optional
        The sensor's image size; the images must have it.

    Returns
    -------
    intrinsics : dict
        ``[camera]`` keys fx_px, fy_px, cx_px, cy_px, distortion.
    rms_px : float
        OpenCV's reprojection RMS.
    """
    board = np.zeros((pattern[0] * pattern[1], 3), np.float32)
    board[:, :2] = np.mgrid[: pattern[0], : pattern[1]].T.reshape(-1, 2) * square_mm
    obj, img, shape = [], [], None
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    for path in images:
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if gray is None:
            raise ValueError(f"{path}: not an image")
        shape = gray.shape[::-1]
        if size is not None and tuple(shape) != tuple(size):
            raise ValueError(f"{path}: image is {shape[0]}x{shape[1]}, the sensor's "
                             f"{size[0]}x{size[1]}")  # fmt: skip
        found, corners = cv2.findChessboardCorners(gray, pattern)
        if found:
            obj.append(board)
            img.append(cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), criteria))
    if len(obj) < 3:
        raise ValueError(f"the chessboard ({pattern[0]}x{pattern[1]}) was found in "
                         f"{len(obj)} of {len(images)} images; at least 3 are needed")  # fmt: skip
    rms, k, dist, _, _ = cv2.calibrateCamera(obj, img, shape, None, None)
    d = [float(v) for v in dist.ravel()[:5]]
    intrinsics = {"fx_px": float(k[0, 0]), "fy_px": float(k[1, 1]), "cx_px": float(k[0, 2]),
                  "cy_px": float(k[1, 2]), "distortion": d}  # fmt: skip
    return intrinsics, float(rms)
