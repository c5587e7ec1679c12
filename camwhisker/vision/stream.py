"""The streaming core: one generator drives the front end over frames and their events.

The trio of the style guide: :class:`~camwhisker.vision.tracker.FrontEnd`
is the small stateful object (``start`` on the rest frame, ``update`` on each
frame after it); :func:`stream` is the one generator over frames, with the
events a live session adds; batch (:func:`camwhisker.run.batch.run_batch`), live
(:class:`camwhisker.live.loop.LiveSession`) and replay
(:func:`camwhisker.live.loop.reprocess_session`) drive it.

Events (a :class:`~camwhisker.io.sources.Frame`'s ``event``):

- ``""``: the next frame;
- ``"rezero"``: the frame becomes the new rest reference (the old one stays in
  use if the features are not found there);
- ``"redetect"``: the features are found again before the update;
- ``"gap"``: no frame came (no image); an untrusted row, the state stays.
- ``"damaged"``: decoded from references a corrupt stretch broke; tracked, so the
  state follows the plate, but an untrusted row.

The rest reference is not one frame's noise. From the rest frame (and from
each re-zero) on, the frames are tracked against that frame's reference while
they stay at rest (:func:`at_rest`), up to ``options.rest_frames`` frames
within ``REST_SPAN_S``; a frame off rest is held out of the mean, and
``REST_EXIT_FRAMES`` in a row end the segment before the last of them (a noisy
read is not motion). The reference
is then rebuilt from their mean image (:func:`~camwhisker.vision.rest.mean_image`),
its points where the first frame's detection found them (no detection to fail).
With ``hold_rest`` (batch) their rows are held back and measured again with
the rebuilt reference, so they come out once the rest segment ends; without it
(live, replay: a row per frame as it comes) they are the first frame's
reference's rows, and the rebuilt reference takes over after them (the frame
that ends the segment pays for the rebuild: one slow live frame). A stream
that moves at once keeps its first frame's reference, and says so.

Each rest reference is checked against the sensor file
(:func:`~camwhisker.vision.mismatch.check_mismatch`): a mismatch is logged as a
warning, and every reference is recorded (:class:`RestRecord`) for the sidecar.
"""

from __future__ import annotations

import contextlib
import copy
import logging
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from camwhisker.sensor.file import Sensor
from camwhisker.vision.mismatch import MismatchCheck, check_mismatch
from camwhisker.vision.rest import mean_image
from camwhisker.vision.tracker import REST_FRAMES, FrameResult, FrontEnd, FrontEndOptions

__all__ = ["Frame", "REST_FRAMES", "EVENTS", "GAP_REASON", "RestRecord", "at_rest", "stream",
           "track", "live_track"]  # fmt: skip

log = logging.getLogger(__name__)

#: Events a frame can carry (a session's timestamps file's ``event`` column).
EVENTS = ("", "rezero", "redetect", "gap", "damaged")
#: Reason written in a row for which no frame came (the error is in the log and sidecar).
GAP_REASON = "no frame: the read failed (camera) or the frame could not be decoded"
DAMAGED_REASON = "decoded from references a corrupt stretch broke (before the next key frame)"
#: ... and the longest span it covers (s, where frames have times): the light drifts
#: over seconds, and a reference averaged over a drift is no frame's.
REST_SPAN_S = 1.0
#: A frame is at rest while its pose, tracked against the rest frame's reference,
#: stays within these of zero: ~4x the rest noise under 2.6 px blur and 5 DN noise
#: (dz, phi), ~20x the shift's; a motion that creeps in below them biases the
#: reference by at most as much.
REST_DZ_MM = 0.05
REST_PHI_DEG = 0.1
REST_SHIFT_MM = 0.02
#: Frames off rest in a row that end a rest segment: one or two reads past the limits
#: are noise (a demosaiced, blurred camera's at-rest phi crosses REST_PHI_DEG one frame
#: in four), held out of the mean; a motion stays past them.
REST_EXIT_FRAMES = 3
#: Fewest rest frames whose points' scatter the mismatch check uses (fewer: its default).
SCATTER_MIN_FRAMES = 5
#: Said where a rest reference comes from one frame.
ONE_FRAME_WARNING = ("rest reference from one frame (no frame at rest after it): its noise "
                     "offsets every row; start a recording with ~1 s at rest")  # fmt: skip


@dataclass(frozen=True)
class Frame:
    """One frame of a source.

    index: 0-based frame number; t_s: time (s); image: ndarray, shape (H, W, 3),
    uint8 BGR, or None where no frame came (a gap in a live session); event:
    "", "rezero", "redetect" or "gap" (see :mod:`camwhisker.vision.stream`).
    """

    index: int
    t_s: float
    image: np.ndarray | None
    event: str = ""


@dataclass(frozen=True)
class RestRecord:
    """One rest reference the stream built: its first frame, how many frames it
    was built from, the mismatch check, the warnings given, and the blur measured
    at it (colour shares, tip's edge; Gaussian sigma, px; NaN: not measured)."""

    frame: int
    frames_used: int
    mismatch: MismatchCheck
    warnings: tuple[str, ...] = ()
    blur_px: tuple[float, float] = (math.nan, math.nan)

    def as_dict(self) -> dict:
        shares, tip = (round(b, 3) if math.isfinite(b) else None for b in self.blur_px)
        return {
            "frame": self.frame,
            "frames_used": self.frames_used,
            "mismatch_check": self.mismatch.as_dict(),
            "warnings": list(self.warnings),
            "blur_px": {"colour_shares": shares, "tip_edge": tip},
        }


def _record(fe: FrontEnd, segment: _RestSegment, used: int, warnings: list[str],
            rest_log: list | None) -> None:  # fmt: skip
    """Check a new rest reference against the sensor file; log and record it."""
    check = check_mismatch(fe.rest, fe.model, segment.scatter_px() if used > 1 else None)
    if check.warned:
        warnings = warnings + [check.message]
    index = segment.frames[0].index
    for text in warnings:
        log.warning("frame %d: %s", index, text)
    if rest_log is not None:
        blur = (fe.rest.share_blur_px, fe.rest.tip_blur_px)
        rest_log.append(RestRecord(index, used, check, tuple(warnings), blur))


def at_rest(r: FrameResult) -> bool:
    """Whether a frame tracked against the rest frame's reference is still at rest:
    trusted, with its pose within REST_DZ_MM, REST_PHI_DEG and REST_SHIFT_MM of zero."""
    dz_mm, phi_deg, _ = r.model
    shift_mm = max(abs(r.sx_mm), abs(r.sy_mm))
    near = abs(dz_mm) <= REST_DZ_MM and phi_deg <= REST_PHI_DEG and shift_mm <= REST_SHIFT_MM
    return bool(r.ok) and near


class _RestSegment:
    """The frames at rest from a rest frame on, tracked against its reference."""

    def __init__(self, fe: FrontEnd, frame: Frame, result: FrameResult):
        self.fe = fe
        self.frames = [frame]  # every frame of the segment, in order
        self.results = [result]
        self.still = [True]  # ... and whether it was at rest (in the mean)
        self.off = 0  # frames off rest at the end, in a row

    @property
    def used(self) -> int:
        """Frames at rest: those the mean is built from."""
        return sum(self.still)

    def take(self, frame: Frame) -> FrameResult | None:
        """``frame``'s row if it joins the segment (at rest, or off rest fewer than
        REST_EXIT_FRAMES in a row); None where the segment ends before it (an event,
        a gap, motion, ``options.rest_frames`` frames or REST_SPAN_S reached)."""
        full = self.used >= self.fe.options.rest_frames
        if frame.event or frame.image is None or full or self._span_s(frame) > REST_SPAN_S:
            return None
        # A shallow copy: update() replaces the state it changes, so a frame that
        # ends the segment leaves the front end as the last rest frame left it.
        trial = copy.copy(self.fe)
        try:
            r = trial.update(frame.image, frame.index)
        except ValueError:  # another size: the stream's own path handles it
            return None
        still = at_rest(r)
        if not still and (not r.ok or self.off + 1 >= REST_EXIT_FRAMES):
            return None
        self.off = 0 if still else self.off + 1
        self.fe = trial
        self.frames.append(frame)
        self.results.append(r)
        self.still.append(still)
        return r

    def _span_s(self, frame: Frame) -> float:
        """Time from the segment's first frame to ``frame`` (s; 0 without times)."""
        span = frame.t_s - self.frames[0].t_s
        return span if math.isfinite(span) else 0.0

    def scatter_px(self) -> np.ndarray:
        """Each point's scatter over the segment (px, per coordinate) over sqrt(frames):
        the noise of their mean; NaN with fewer than SCATTER_MIN_FRAMES frames."""
        if self.used < SCATTER_MIN_FRAMES:
            return np.full(self.results[0].points_uv.shape[0], np.nan)
        uv = np.stack([r.points_uv for r, s in zip(self.results, self.still, strict=True) if s])
        sd = np.sqrt(np.nanmean(np.nanvar(uv, axis=0, ddof=1), axis=-1))
        return sd / math.sqrt(self.used)

    def rebuild(self):
        """The front end with the reference rebuilt from the segment's mean image,
        the frames it used and the warnings; the first frame's where it is alone
        or the features are not found in the mean."""
        first = self.frames[0].index
        if self.used == 1:
            return self.fe, 1, [ONE_FRAME_WARNING] if self.fe.options.rest_frames > 1 else []
        # The first frame's front end, copied: start() replaces its state, and its model
        # and cloth samples are this sensor's already (a new one costs ~5 ms).
        fe = copy.copy(self.fe)
        try:
            images = [f.image for f, s in zip(self.frames, self.still, strict=True) if s]
            fe.start(mean_image(images), first, self.fe.rest.uv)
        except ValueError as exc:  # FeaturesNotFound is one
            last = self.frames[-1].index
            return self.fe, 1, [f"rest frames {first}-{last}: their mean failed ({exc}); "
                                f"frame {first} alone is the reference"]  # fmt: skip
        return fe, self.used, []


def _close(segment: _RestSegment, hold: bool, rest_log: list | None):
    """End a rest segment: rebuild the reference, record it, and (``hold``) yield the
    segment's rows measured with it. Returns the front end to go on with."""
    fe, used, warnings = segment.rebuild()
    _record(fe, segment, used, warnings, rest_log)
    if hold:
        for frame, r in zip(segment.frames, segment.results, strict=True):
            yield frame, (fe.update(frame.image, frame.index) if used > 1 else r)
    return fe


def _start(
    sensor: Sensor, options: FrontEndOptions | None, image: np.ndarray, index: int, warm_up: bool
) -> tuple[FrontEnd, FrameResult]:
    fe = FrontEnd(sensor, options)
    r = fe.start(image, index)
    if warm_up:
        # A throwaway update of a copy on the rest frame, so that the first real frame
        # finds every compiled kernel of the update loaded (a live latency spike otherwise).
        copy.deepcopy(fe).update(image, index)
    return fe, r


def stream(
    frames: Iterable[Frame],
    sensor: Sensor,
    options: FrontEndOptions | None = None,
    rest_index: int = 0,
    strict: bool = True,
    warm_up: bool = False,
    rest_log: list | None = None,
    hold_rest: bool | None = None,
) -> Iterator[tuple[Frame, FrameResult]]:
    """Yield ``(frame, result)`` for each frame, in order.

    Parameters
    ----------
    frames : iterable of Frame
        Frames with their events (see the module's docstring); ``image`` None is a gap.
    sensor : Sensor
    options : FrontEndOptions, optional
    rest_index : int
        The rest frame; earlier frames give untrusted rows.
    strict : bool
        True (batch): a rest frame without its features, or a frame the front end
        refuses, raises. False (live, replay): it gives an untrusted row and the
        stream goes on; a failed rest frame is tried again on the next frame.
    warm_up : bool
        Run the update once on a copy at each rest frame (live: no slow first frame).
    rest_log : list, optional
        Receives a :class:`RestRecord` for each rest reference built.
    hold_rest : bool, optional
        Hold the rest segment's rows back and measure them again with the rebuilt
        reference (see the module's docstring); default: ``strict`` (batch).

    Raises
    ------
    camwhisker.vision.FeaturesNotFound
        ``strict`` and the rest frame lacks a feature.
    ValueError
        ``rest_index`` is negative; or ``strict`` and a frame has another size.
    """
    if rest_index < 0:
        raise ValueError(f"rest_index must be >= 0, got {rest_index}")
    hold = strict if hold_rest is None else hold_rest
    fe = segment = None
    for frame in frames:
        if segment is not None:
            r = segment.take(frame)
            if r is not None:
                if not hold:
                    yield frame, r
                continue
            fe = yield from _close(segment, hold, rest_log)
            segment = None
        r, started = _step(fe, frame, sensor, options, rest_index, strict, warm_up)
        if started is not None:
            fe, segment = started, _RestSegment(started, frame, r)
            if started.options.rest_frames == 1:  # nothing to average: recorded at once
                fe = yield from _close(segment, False, rest_log)
                segment = None
            elif hold:
                continue
        yield frame, r
    if segment is not None:
        yield from _close(segment, hold, rest_log)


def _step(fe, frame, sensor, options, rest_index, strict, warm_up):
    """One frame outside a rest segment: its row, and the new front end where it
    became a rest frame (else None)."""
    i, image = frame.index, frame.image
    if image is None:
        return FrameResult.untrusted(i, GAP_REASON), None
    if i < rest_index:
        return FrameResult.untrusted(i, "before the rest frame"), None
    if frame.event == "damaged":  # such a frame can read ok and be degrees off
        if fe is not None:
            with contextlib.suppress(ValueError):
                fe.update(image, i)
        return FrameResult.untrusted(i, DAMAGED_REASON), None
    if fe is None or frame.event == "rezero":
        what = "rest frame" if fe is None else "re-zero failed"
        try:
            started, r = _start(sensor, options, image, i, warm_up)
        except ValueError as exc:  # FeaturesNotFound is one
            if strict:
                raise
            return FrameResult.untrusted(i, f"{what}: {exc}"), None
        return r, started
    try:
        if frame.event == "redetect":
            fe.redetect(image)
        return fe.update(image, i), None
    except ValueError as exc:  # a frame of another size after a reconnect
        if strict:
            raise
        return FrameResult.untrusted(i, str(exc)), None


def track(
    images: Iterable[np.ndarray],
    sensor: Sensor,
    options: FrontEndOptions | None = None,
    rest_index: int = 0,
) -> Iterator[FrameResult]:
    """:func:`stream` over bare images (no clock, no events): one result per image.

    Raises
    ------
    FeaturesNotFound
        The rest frame lacks a feature.
    """
    frames = (Frame(i, math.nan, image) for i, image in enumerate(images))
    return (r for _, r in stream(frames, sensor, options, rest_index))


def live_track(
    items: Iterable[tuple[np.ndarray | None, str]],
    sensor: Sensor,
    options: FrontEndOptions | None = None,
) -> Iterator[FrameResult]:
    """:func:`stream` as live runs it, over ``(image, event)`` pairs: one result per pair."""
    frames = (Frame(i, math.nan, image, event) for i, (image, event) in enumerate(items))
    return (r for _, r in stream(frames, sensor, options, strict=False, warm_up=True))
