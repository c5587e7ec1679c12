"""The streaming core: one generator drives the front end over frames and their events.

The trio of the style guide: :class:`~camwhisker.vision.tracker.FrontEnd`
is the small stateful object (``start`` on the rest frame, ``update`` on each
frame after it); :func:`stream` is the one generator over frames, with the
events a live session adds; batch (:func:`camwhisker.batch.run_batch`), live
(:class:`camwhisker.live.loop.LiveSession`) and replay
(:func:`camwhisker.live.loop.reprocess_session`) drive it.

Events (a :class:`~camwhisker.sources.Frame`'s ``event``):

- ``""``: the next frame;
- ``"rezero"``: the frame becomes the new rest reference (the old one stays in
  use if the features are not found there);
- ``"redetect"``: the features are found again before the update;
- ``"gap"``: no frame came (no image); an untrusted row, the state stays.

Each rest reference is checked against the sensor file
(:func:`~camwhisker.vision.mismatch.check_mismatch`): a mismatch is logged as a
warning, and every reference is recorded (:class:`RestRecord`) for the sidecar.
"""

from __future__ import annotations

import copy
import logging
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from camwhisker.sensor import Sensor
from camwhisker.sources import Frame
from camwhisker.vision.mismatch import MismatchCheck, check_mismatch
from camwhisker.vision.tracker import FrameResult, FrontEnd, FrontEndOptions

__all__ = ["EVENTS", "GAP_REASON", "RestRecord", "stream", "track", "live_track"]

log = logging.getLogger(__name__)

#: Events a frame can carry (a session's timestamps file's ``event`` column).
EVENTS = ("", "rezero", "redetect", "gap")
#: Reason written in a row for which no frame came (the error is in the log and sidecar).
GAP_REASON = "no frame: capture read failed"


@dataclass(frozen=True)
class RestRecord:
    """One rest reference the stream built: its first frame, how many frames it
    was built from, the mismatch check, and the warnings given."""

    frame: int
    frames_used: int
    mismatch: MismatchCheck
    warnings: tuple[str, ...] = ()

    def as_dict(self) -> dict:
        return {
            "frame": self.frame,
            "frames_used": self.frames_used,
            "mismatch_check": self.mismatch.as_dict(),
            "warnings": list(self.warnings),
        }


def _record(fe: FrontEnd, index: int, rest_log: list | None) -> None:
    """Check the new rest reference against the sensor file; log and record it."""
    check = check_mismatch(fe.rest, fe.model)
    warnings = (check.message,) if check.warned else ()
    for text in warnings:
        log.warning("frame %d: %s", index, text)
    if rest_log is not None:
        rest_log.append(RestRecord(index, 1, check, warnings))


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

    Raises
    ------
    camwhisker.vision.FeaturesNotFound
        ``strict`` and the rest frame lacks a feature.
    ValueError
        ``rest_index`` is negative; or ``strict`` and a frame has another size.
    """
    if rest_index < 0:
        raise ValueError(f"rest_index must be >= 0, got {rest_index}")
    fe = None
    for frame in frames:
        i, image = frame.index, frame.image
        if image is None:
            r = FrameResult.untrusted(i, GAP_REASON)
        elif i < rest_index:
            r = FrameResult.untrusted(i, "before the rest frame")
        elif fe is None or frame.event == "rezero":
            what = "rest frame" if fe is None else "re-zero failed"
            try:
                fe, r = _start(sensor, options, image, i, warm_up)
                _record(fe, i, rest_log)
            except ValueError as exc:  # FeaturesNotFound is one
                if strict:
                    raise
                r = FrameResult.untrusted(i, f"{what}: {exc}")
        else:
            try:
                if frame.event == "redetect":
                    fe.redetect(image)
                r = fe.update(image, i)
            except ValueError as exc:  # a frame of another size after a reconnect
                if strict:
                    raise
                r = FrameResult.untrusted(i, str(exc))
        yield frame, r


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
