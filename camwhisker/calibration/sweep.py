"""Calibrate a build from its sweep videos: track, adjust, track again with the fit.

The front end tracks the sweep with the current sensor estimate; its image
points (:attr:`FrameResult.points_uv`) go to the bundle adjustment
(:mod:`camwhisker.calibration.adjust`), and the fitted file tracks the sweep
again: with the nominal file a real build loses frames, with a fitted one it
does not. Rounds stop when the fit no longer moves by more than a fraction
of its standard errors.

Each video starts at rest: its first frame is the front end's rest frame, and
the frames before the plate first moves are held at pose zero. The square's
side, measured with calipers, fixes the scale. Each video's tracked corners
are its rest reference's detected corners carried along; where they lie off
the true corners is measured by the crossings of the corners' edges in the
moving frames (:func:`corner_offsets`), and the adjustment fits that offset as the
corner's shift in the plate. The rod's diameter (which the adjustment cannot
see, and the front end's tip measurement needs) is measured from the tip's
radius at rest in the first round, then from its edge in the last round's
tilted frames against that round's fit (:func:`tilted_rim_scale`), less the
blur's inward shift of that curved edge, with the blur measured across it.
Intrinsics from chessboard images (:func:`intrinsics_from_chessboard`) may be
given; they are then held.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from camwhisker.calibration import MAX_ROUNDS
from camwhisker.calibration.adjust import (
    KNOWN_DZ_SD_MM,
    Adjustment,
    adjust_geometry,
    corner_shift_jacobian,
)
from camwhisker.contact.stage import (
    StageLog,
    StageLogError,
    detect_pauses,
    estimate_offset,
    log_pause_medians,
    pause_frames,
)
from camwhisker.io.sources import lossy_codec, open_source
from camwhisker.sensor.camera import INTRINSIC_NAMES
from camwhisker.sensor.file import Sensor
from camwhisker.sensor.model import TIP, PlateModel
from camwhisker.sensor.polygon import polygon_centroid
from camwhisker.vision.colour import unmixed_maps
from camwhisker.vision.mismatch import edge_crossings
from camwhisker.vision.stream import track
from camwhisker.vision.tip import (
    brightness,
    edge_blur_px,
    rim_centre,
    rim_scale,
    tip_edge_points,
)
from camwhisker.vision.tracker import TIP_SEARCH_PX, FrontEnd, FrontEndOptions

__all__ = [
    "REST_PX",
    "MAX_ROUNDS",
    "SWEEP_APEX_MASK_PX",
    "TrackedSweep",
    "SensorFit",
    "track_sweep",
    "rest_frames",
    "corner_offsets",
    "rest_tip_radius_px",
    "tilted_rim_scale",
    "rod_diameter_mm",
    "calibrate_sensor",
    "lossy_steps_warnings",
    "adjust_tracked",
    "intrinsics_from_chessboard",
]

#: A leading frame is at rest while every point stays this close to the first
#: frame's (px): above the tip's scatter at rest on noisy builds (~0.45 px), below
#: its move at 0.06 deg. Every point, not their median: the tip moves first.
REST_PX = 0.5
#: The sweep's corners are tracked without their apex (px, FrontEndOptions.apex_mask_px):
#: the phi scale comes from the corners' foreshortening, which blur's rounding of the
#: apex biases at the 0.02 px level under tilt; the edges' half levels it does not move.
SWEEP_APEX_MASK_PX = 4.0
#: ... and their square's corners without the cloth farther than this outside the square's
#: edges (px, FrontEndOptions.square_band_px): the springs' ends reach into those windows
#: as the plate tilts, an error that grows with the tilt and that the fit takes into the
#: depths; beyond ~3 blur sigma the edge's profile has no more to give.
SWEEP_SQUARE_BAND_PX = 8.0
#: The tip's size is measured in frames tilted at least this far (deg): the face then
#: lies on the cloth, as in use; at rest it lies on the cross and its light centre,
#: whose dark red the edge search can leave out.
TILTED_TIP_MIN_DEG = 10.0
#: ... in this many of them at most, spread over the sweep (the scale's SD per frame
#: is ~0.002, so the median's is ~0.0003), and in this many at least (fewer: a round
#: tracked with a file far off, whose poses misplace the rim; the rest frame then).
TILTED_TIP_FRAMES = 40
MIN_TILTED_TIP_FRAMES = 20
#: The blur across the tip's edge is measured in the first this many of them: one
#: lens, and each frame's median over its rays is within ~0.05 px.
BLUR_FRAMES = 8
#: Rounds go on while the tilted frames find the rim off by more than this (relative):
#: 0.1 % of the rod's diameter moves phi by ~0.005 deg.
RIM_SCALE_TOL = 0.001
#: The fit is stable when no parameter moved by more than this many SE in a round.
STABLE_SE = 0.5
#: The corners' crop reaches this far beyond them (px): their edges' profiles.
CORNER_BOX_PX = 16
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
    t_s : ndarray, shape (F,); each frame's time in its video (s)
    corner_offsets_uv : ndarray, shape (V, 12, 2); each video's tracked corners minus
        the true ones, as offsets at rest (:func:`corner_offsets`), NaN where not measured
    """

    points_uv: np.ndarray
    q: np.ndarray
    ok: np.ndarray
    rest: np.ndarray
    video: np.ndarray
    t_s: np.ndarray
    corner_offsets_uv: np.ndarray


@dataclass(frozen=True)
class SensorFit:
    """The calibrated geometry and how it was reached.

    adjustment : the last round's :class:`Adjustment`
    tracked : the last round's :class:`TrackedSweep` (tracked with the previous fit)
    ok_fraction : the fraction of ok rows in each round's tracking
    """

    adjustment: Adjustment
    tracked: TrackedSweep
    ok_fraction: list = field(default_factory=list)
    #: The tip's radius at rest (px), mean over the videos: the first round's rod diameter.
    tip_radius_px: float = float("nan")
    #: The tip's edge over the model's rim in the tilted frames of the round before the
    #: last (:func:`tilted_rim_scale`), and those frames' count: the rod diameter since.
    rim_scale: float = float("nan")
    rim_frames: int = 0
    #: The blur across the tip's edge in those frames (Gaussian sigma, px).
    rim_blur_px: float = float("nan")

    @property
    def sensor(self) -> Sensor:
        return self.adjustment.sensor


def rest_frames(points_uv: np.ndarray) -> np.ndarray:
    """The leading run of frames whose points all stay within ``REST_PX`` of frame 0's."""
    d = np.linalg.norm(points_uv - points_uv[0], axis=-1)
    with np.errstate(all="ignore"):
        still = np.nanmax(d, axis=1) <= REST_PX
    run = int(np.argmin(still)) if not still.all() else len(still)
    out = np.zeros(len(points_uv), dtype=bool)
    out[: max(run, 1)] = True
    return out


def corner_offsets(video: str | Path, tracked: TrackedSweep, k: int, sensor: Sensor,
                   options: FrontEndOptions | None = None) -> np.ndarray:  # fmt: skip
    """Where video ``k``'s tracked corners lie off the true corners, as offsets at rest
    (px), shape (12, 2): in each trusted frame off rest, the tracked corner minus the
    crossing of its edges' lines (:func:`~camwhisker.vision.mismatch.edge_crossings`,
    which blur does not move), carried into the plate at the frame's pose and out
    again at rest; the median over the frames. The moving frames, not the rest ones:
    compression moves an edge by up to ~1 px, the same way in every still frame but
    differently as the edge crosses the blocks. NaN where no frame found the edges.
    ``tracked`` (without its offsets yet) was tracked with ``sensor``; :func:`track_sweep`
    measures them as it tracks, without this second pass over the video.
    """
    mine = np.flatnonzero(tracked.video == k)
    use = tracked.ok[mine] & ~tracked.rest[mine]
    measure, found = _CornerOffsets(sensor, options), []
    for i, frame in enumerate(open_source(video)):
        measure.see(frame.image)
        if i < len(use) and use[i]:
            found.append(measure(frame.image, tracked.points_uv[mine[i]], tracked.q[mine[i]]))
    return measure.median(found)


class _CornerOffsets:
    """:func:`corner_offsets` frame by frame: shown each of the video's images in order
    (:meth:`see`) and called with a frame's image, tracked points (13, 2) and pose (5,),
    it returns that frame's offsets at rest (12, 2); :meth:`median` is over frames."""

    def __init__(self, sensor: Sensor, options: FrontEndOptions | None):
        self.sensor, self.options, self.fe = sensor, options, None
        self.model = PlateModel(sensor)
        self.at_rest = corner_shift_jacobian(self.model, np.zeros(5))

    def see(self, image: np.ndarray) -> None:
        if self.fe is None:  # the video's first frame: its rest reference's weights
            self.fe = FrontEnd(self.sensor, self.options)
            self.fe.start(image)

    def __call__(self, image: np.ndarray, points_uv: np.ndarray, q: np.ndarray) -> np.ndarray:
        uv = points_uv[:TIP]
        box = np.floor(np.nanmin(uv, axis=0)).astype(int) - CORNER_BOX_PX
        h, w = image.shape[:2]
        u0, v0 = np.clip(box, 0, [w - 1, h - 1])
        u1, v1 = np.ceil(np.nanmax(uv, axis=0)).astype(int) + CORNER_BOX_PX
        crop = image[v0:v1, u0:u1]
        red, blue = unmixed_maps(crop, self.fe.rest.weights, self.fe.gains(image))
        edges, _ = edge_crossings(red, blue, uv - (u0, v0), self.model.edge_directions(q))
        shift = np.linalg.solve(corner_shift_jacobian(self.model, q),
                                (uv - edges - (u0, v0))[..., None])  # fmt: skip
        return (self.at_rest @ shift)[..., 0]

    @staticmethod
    def median(found: list) -> np.ndarray:
        """The median of the frames' offsets ``found``; NaN where none."""
        if not found:
            return np.full((TIP, 2), np.nan)
        with np.errstate(all="ignore"):
            return np.nanmedian(found, axis=0)


class _TipViews:
    """Each video's first image and, in each frame tilted near TILTED_TIP_MIN_DEG or beyond,
    the tip's surroundings and the frame's white-balance gains: kept as a round tracks the
    sweep, so that the rim is measured against the round's fit (:func:`tilted_rim_scale`)
    without decoding the videos again."""

    #: Frames tilted this much less than TILTED_TIP_MIN_DEG are kept too: the fit's poses
    #: differ from the tracking's by far less.
    MARGIN_DEG = 1.0

    def __init__(self, sensor: Sensor):
        # The tip's search window (tip_edge_points) with room for a larger fitted rod
        # and for the blur's profiles across the edge.
        self.half_px = int(1.4 * 1.2 * _rim_radius_px(sensor) + TIP_SEARCH_PX + 8)
        self.first: dict[int, np.ndarray] = {}
        self.views: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def see(self, video: int, frame: int, image: np.ndarray, tip_uv: np.ndarray,
            phi_deg: float, fe: FrontEnd) -> None:  # fmt: skip
        """Keep what the rim's measurement needs of ``frame`` (index over the sweep), the
        gains as ``fe`` (the round's front end) finds them."""
        if video not in self.first:
            self.first[video] = image
        if not (np.isfinite(tip_uv).all() and phi_deg >= TILTED_TIP_MIN_DEG - self.MARGIN_DEG):
            return
        u, v = np.round(tip_uv).astype(int)
        u0, v0 = max(u - self.half_px, 0), max(v - self.half_px, 0)
        crop = image[v0 : v + self.half_px + 1, u0 : u + self.half_px + 1].copy()
        self.views[frame] = (np.array([u0, v0], float), crop, fe.gains(image))


def rest_tip_radius_px(video: str | Path, sensor: Sensor,
                       options: FrontEndOptions | None = None) -> float:  # fmt: skip
    """The end face's radius (px) in the video's first frame: the median distance of
    its edge points from its centre as the front end measures it (the model's rim
    fitted to the edge clear of the rod). A median, since a tilted rod's flank
    beside the face reads as edge a few px outside it.

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
    rim, rod, _ = fe.model.outlines(np.zeros(5))
    offset = fe.rest.offsets[TIP]
    tip = rim_centre(edges, rim + offset, rod + offset) if edges is not None else None
    if tip is None or not tip.ok:
        raise ValueError(f"{video}: the tip's edge at rest: {why or tip.reason}")
    return float(np.median(np.linalg.norm(edges - tip.centre_uv, axis=1)))


def _rim_radius_px(sensor: Sensor) -> float:
    """The model's end-face rim at rest: its mean radius about its centroid (px)."""
    rim = PlateModel(sensor).outlines(np.zeros(5))[0]
    return float(np.mean(np.linalg.norm(rim - polygon_centroid(rim), axis=1)))


def tilted_rim_scale(
    views: _TipViews,
    sensor: Sensor,
    tracked: TrackedSweep,
    options: FrontEndOptions | None = None,
) -> tuple[float, int, float]:
    """How much larger the end face is than ``sensor``'s rim in the sweep's frames
    tilted beyond TILTED_TIP_MIN_DEG (median of :func:`~camwhisker.vision.tip.rim_scale`
    over at most TILTED_TIP_FRAMES of them, at the tracked poses, the blur's inward
    shift of the edge taken out), how many frames gave one, and the blur (Gaussian
    sigma, px; :func:`~camwhisker.vision.tip.edge_blur_px`, median over BLUR_FRAMES
    of them; NaN, and no shift taken out, where no edge fits); (NaN, 0, NaN) where no
    frame gives a scale. ``tracked``'s points place the search, its poses are ``sensor``'s;
    ``views`` holds the frames, kept as they were tracked."""
    phi = np.degrees(np.hypot(tracked.q[:, 1], tracked.q[:, 2]))
    tilted = np.flatnonzero(tracked.ok & ~tracked.rest & (phi >= TILTED_TIP_MIN_DEG))
    if not len(tilted):
        return float("nan"), 0, float("nan")
    keep = np.unique(np.linspace(0, len(tilted) - 1, TILTED_TIP_FRAMES).round().astype(int))
    pick = set(tilted[keep].tolist())
    model, radius_px, faces, blurs = PlateModel(sensor), _rim_radius_px(sensor), [], []
    for k in np.unique(tracked.video[sorted(pick)]):
        fe = FrontEnd(sensor, options)
        fe.start(views.first[k])
        for f in sorted(f for f in pick if tracked.video[f] == k and f in views.views):
            origin, crop, gains = views.views[f]
            guess = tracked.points_uv[f, TIP] - origin
            rim, rod, _ = model.outlines(tracked.q[f])
            off = fe.rest.offsets[TIP] - origin
            edges, _, _ = tip_edge_points(crop, gains, guess, radius_px, TIP_SEARCH_PX)
            if edges is None:
                continue
            if len(blurs) < BLUR_FRAMES:
                blurs.append(edge_blur_px(brightness(crop, gains)[1], edges, rim + off, rod + off))
            faces.append((edges + origin, rim + off + origin, rod + off + origin))
    blur = float(np.nanmedian(blurs)) if np.isfinite(blurs).any() else float("nan")
    scales = np.array([rim_scale(*face, np.nan_to_num(blur)) for face in faces])
    scales = scales[np.isfinite(scales)]
    if not len(scales):
        return float("nan"), 0, float("nan")
    return float(np.median(scales)), len(scales), blur


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
    views: _TipViews | None = None,
) -> TrackedSweep:
    """Track every video of the sweep with ``sensor`` (and ``options``, such as the
    user's rough feature positions); ``on_frame`` is called per frame; ``views`` is
    filled with the frames the rim's measurement needs.

    Raises
    ------
    camwhisker.vision.FeaturesNotFound
        A video's first frame lacks a feature.
    """
    parts, offsets, n_before = [], [], 0
    for k, video in enumerate(videos):
        times: list[float] = []
        # The images whose rows the tracker holds back (a rest segment's): the corners'
        # offsets are measured on each image as its row comes, not in a second decode.
        waiting: dict[int, np.ndarray] = {}
        images = _images_noting_times(video, times, waiting)
        results, found, measure = [], [], _CornerOffsets(sensor, options)
        for i, r in enumerate(track(images, sensor, options)):
            results.append(r)
            image = waiting.pop(i)
            measure.see(image)
            if views is not None:
                views.see(k, n_before + i, image, np.asarray(r.points_uv[TIP], dtype=float),
                          r.phi_deg, measure.fe)  # fmt: skip
            found.append(measure(image, np.asarray(r.points_uv, dtype=float),
                                 _q_from_results([r])[0]) if r.ok else None)  # fmt: skip
            if on_frame is not None:
                on_frame()
        if not results:
            raise ValueError(f"{video}: no frames")
        pts = np.array([r.points_uv for r in results], dtype=float).reshape(-1, TIP + 1, 2)
        ok, rest = np.array([r.ok for r in results]), rest_frames(pts)
        offsets.append(measure.median([f for f, u in zip(found, ok & ~rest, strict=True) if u]))
        parts.append((pts, _q_from_results(results), ok, rest, np.full(len(results), k),
                      np.array(times[: len(results)])))  # fmt: skip
        n_before += len(results)
    return TrackedSweep(*(np.concatenate(c) for c in zip(*parts, strict=True)),
                        np.array(offsets))  # fmt: skip


def _images_noting_times(video: str | Path, times: list, images: dict) -> Iterator[np.ndarray]:
    """The video's images, each frame's time appended to ``times`` and its image kept
    in ``images`` by its index as it passes."""
    for i, frame in enumerate(open_source(video)):
        times.append(frame.t_s)
        images[i] = frame.image
        yield frame.image


def known_dz_from_stage(tracked: TrackedSweep, k: int, log: StageLog
                        ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Each frame's known dz (mm; NaN where none) in video ``k`` from its stage log of
    known axial steps (the paper's test 2), and its SD (mm): the log's median dz over
    each pause for the trusted frames inside it, the clocks aligned on the front end's
    dz; each pause counts as one step of SD ``KNOWN_DZ_SD_MM``.

    Raises
    ------
    StageLogError
        The log has no dz_mm column, or its clock cannot be aligned with the video's.
    """
    if log.dz_mm is None:
        raise StageLogError(f"{log.source}: no dz_mm column: known dz steps need it")
    sel = np.flatnonzero(tracked.video == k)
    t, dz = tracked.t_s[sel], tracked.q[sel, 0]
    offset_s, _ = estimate_offset(log, t, dz)  # dz in phi's place: the one signal that moves
    if not np.isfinite(offset_s):
        raise StageLogError(f"{log.source}: its pauses cannot be aligned with the video's dz")
    pauses = detect_pauses(log)
    applied = log_pause_medians(log, log.dz_mm, pauses)
    known, sd = np.full((2, len(tracked.video)), np.nan)
    for frames, value in zip(pause_frames(t, tracked.ok[sel], pauses, offset_s), applied,
                             strict=True):  # fmt: skip
        known[sel[frames]] = value
        sd[sel[frames]] = KNOWN_DZ_SD_MM * np.sqrt(len(frames))
    return known, sd


def calibrate_sensor(
    videos: Sequence[str | Path],
    sensor: Sensor,
    square_side_mm: float | None,
    intrinsics: dict | None = None,
    rounds: int = MAX_ROUNDS,
    on_frame: Callable[[], None] | None = None,
    on_round: Callable[[int, Adjustment], None] | None = None,
    options: FrontEndOptions | None = None,
    dz_steps: Sequence[tuple[str | Path, StageLog]] = (),
) -> SensorFit:
    """Fit a build's geometry to its sweep videos, starting from the nominal ``sensor``.

    Parameters
    ----------
    videos : sequence of path
        Sweep videos, each starting at rest.
    sensor : Sensor
        The nominal sensor file.
    square_side_mm : float or None
        The square's side measured with calipers: fixes the scale. None: the scale
        comes from ``dz_steps``.
    intrinsics : dict, optional
        ``[camera]`` keys (fx_px, fy_px, cx_px, cy_px, distortion) from a separate
        calibration: held at these values.
    rounds : int
        Rounds of tracking and adjustment at most.
    on_frame, on_round : callable, optional
        Progress: called per tracked frame, and after each round with its index and fit.
    options : FrontEndOptions, optional
        How the front end tracks the sweep (``features``: rough rest positions);
        its corners without their apex (``SWEEP_APEX_MASK_PX``).
    dz_steps : sequence of (path, StageLog)
        Videos of known axial steps (the paper's test 2), each with its stage log
        (a ``dz_mm`` column): tracked with the sweep, their pauses' dz known.

    Returns
    -------
    SensorFit
    """
    if rounds < 1:
        raise ValueError(f"rounds must be >= 1, got {rounds}")
    start, fixed = _start(sensor, square_side_mm, intrinsics, bool(dz_steps))
    videos = [*videos, *(v for v, _ in dz_steps)]
    options = replace(options or FrontEndOptions(), apex_mask_px=SWEEP_APEX_MASK_PX,
                      square_band_px=SWEEP_SQUARE_BAND_PX)  # fmt: skip
    current, previous, ok_fraction = start, None, []
    scale, n_scaled, blur = float("nan"), 0, float("nan")
    for k in range(rounds):
        if n_scaled >= MIN_TILTED_TIP_FRAMES:  # the tip's edge in the last round's tilted frames
            fixed[ROD_DIAMETER] *= 1.0 + scale
            used = (scale, n_scaled, blur)
        else:  # at rest, the rim placed and the rod's flank told apart by the fit so far
            radius_px = float(np.mean([rest_tip_radius_px(v, current, options) for v in videos]))
            fixed[ROD_DIAMETER] = rod_diameter_mm(current, radius_px)
            used = (float("nan"), 0, float("nan"))
        current = current.replace(plate={"rod_diameter_mm": fixed[ROD_DIAMETER]})
        views = _TipViews(current)
        tracked = track_sweep(videos, current, on_frame, options, views)
        ok_fraction.append(float(tracked.ok.mean()))
        # Only the rows the front end trusted: a lost track's points are no measurement.
        pts = np.where((tracked.ok | tracked.rest)[:, None, None], tracked.points_uv, np.nan)
        known_dz, known_sd = np.full((2, len(pts)), np.nan)
        for j, (_, log) in enumerate(dz_steps):
            known, sd = known_dz_from_stage(tracked, len(videos) - len(dz_steps) + j, log)
            has = np.isfinite(known)
            known_dz[has], known_sd[has] = known[has], sd[has]
        tracked = replace(tracked, rest=_steps_rest(tracked, known_dz))
        adj = adjust_tracked(tracked, pts, start, fixed, known_dz, known_sd)
        if on_round is not None:
            on_round(k, adj)
        current = adj.sensor
        if k == rounds - 1:  # no round after it to use the rim's scale
            break
        # The rim measured against this round's fit, its geometry and poses: against the
        # tracking's (the round before's fit) the rod's size lags the depths and swings.
        fitted = replace(tracked, q=np.where(adj.used[:, None], adj.q, tracked.q))
        scale, n_scaled, blur = tilted_rim_scale(views, current, fitted, options)
        rim_off = n_scaled >= MIN_TILTED_TIP_FRAMES and abs(scale) > RIM_SCALE_TOL
        if previous is not None and _stable(previous, adj) and not rim_off:
            break
        previous = adj
    adj = replace(adj, warnings=[*adj.warnings, *lossy_steps_warnings(dz_steps)])
    return SensorFit(adj, tracked, ok_fraction, radius_px, *used)


def lossy_steps_warnings(dz_steps) -> list[str]:
    """A warning per dz-steps video that a lossy codec stored: its quantisation moves
    each corner by 0.1-0.5 px at a 0.1 mm step (``camwhisker dev subpixel-bench``)."""
    out = []
    for video, _ in dz_steps:
        codec = lossy_codec(video)
        if codec:
            out.append(f"{video}: the dz steps were stored by a lossy codec ({codec}), whose "
                       "quantisation misplaces the corners by 0.1-0.5 px at 0.1 mm steps and "
                       "the steps' dz gain by ~1-2 %; record them uncompressed (the camera's "
                       "YUYV, PNG frames, FFV1 or x264 at QP 0)")  # fmt: skip
    return out


def _steps_rest(tracked: TrackedSweep, known_dz: np.ndarray) -> np.ndarray:
    """The rest flags, a video with known dz at rest only until its last frame known at
    dz zero before its first step: the rest test (REST_PX) takes the first ramp's
    frames for rest (0.1 mm moves the corners ~0.6 px), the stage log does not."""
    rest = tracked.rest.copy()
    frame = np.arange(len(rest))
    for k in np.unique(tracked.video[np.isfinite(known_dz)]):
        mine = tracked.video == k
        moved = np.flatnonzero(mine & (np.nan_to_num(known_dz) != 0))
        zero = np.flatnonzero(mine & (known_dz == 0) & (frame < moved.min(initial=len(rest))))
        if len(zero):
            rest[mine & (frame > zero.max())] = False
    return rest


def adjust_tracked(tracked: TrackedSweep, points_uv: np.ndarray, start: Sensor, fixed: dict,
                   known_dz_mm: np.ndarray | None = None,
                   known_dz_sd_mm: np.ndarray | float = KNOWN_DZ_SD_MM) -> Adjustment:  # fmt: skip
    """One round's adjustment of ``points_uv`` (the tracked sweep's trusted points, NaN
    elsewhere) from ``start``: the corners' shifts fitted about the sweep's measured
    offsets, each frame starting at its tracked pose."""
    return adjust_geometry(points_uv, start, tracked.rest, fixed, tracked.q, corner_shifts=True,
                           corner_offsets_uv=tracked.corner_offsets_uv, video=tracked.video,
                           known_dz_mm=known_dz_mm, known_dz_sd_mm=known_dz_sd_mm)  # fmt: skip


def _start(sensor: Sensor, square_side_mm: float | None, intrinsics: dict | None,
           dz_steps: bool) -> tuple[Sensor, dict]:  # fmt: skip
    """The adjustment's starting sensor and its fixed parameters: the square's side,
    the intrinsics where given."""
    if square_side_mm is None and not dz_steps:
        raise ValueError("give the square's side (square_side_mm) or known dz steps: "
                         "the images alone do not fix the scale")  # fmt: skip
    fixed = {}
    if square_side_mm is not None:
        if not square_side_mm > 0:
            raise ValueError(f"square_side_mm must be positive, got {square_side_mm}")
        fixed[SQUARE_SIDE] = float(square_side_mm)
    start = sensor.replace(plate={"square_side_mm": fixed.get(SQUARE_SIDE,
                                                              sensor.plate.square_side_mm)})
    if intrinsics:
        start = start.replace(camera=intrinsics)
        cam = start.camera
        values = [cam.fx_px, cam.fy_px, cam.cx_px, cam.cy_px, *cam.distortion]
        fixed.update({f"camera.{n}": v for n, v in zip(INTRINSIC_NAMES, values, strict=True)})
    return start, fixed


def _stable(before: Adjustment, after: Adjustment) -> bool:
    """No fitted parameter moved by more than ``STABLE_SE`` of its SE from the data,
    none changed hold."""
    if set(before.held) != set(after.held):
        return False
    free = np.isfinite(after.se_data)
    moved = np.abs(after.value - before.value)[free]
    return bool(np.all(moved <= STABLE_SE * after.se_data[free]))


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
