"""The grabber: a thread that reads a capture as fast as it delivers.

Reading in its own thread keeps the driver's queue empty, so a frame is never
handed on stale because the processing took long. Two modes:

- ``"latest"`` (control): one slot; a new frame replaces one not yet taken,
  and the replaced frame is counted in :attr:`GrabberStats.dropped`. The
  backlog is at most one frame, so a result is always about the newest frame.
- ``"every"`` (recording): a FIFO of up to ``capacity`` frames; nothing is
  dropped unless it overflows (then the newest is dropped and counted).

Every item carries a sequence number (0, 1, 2, ... over everything the
grabber produced) and its monotonic time: the driver's buffer time where the
capture gives one on that clock (a V4L2 camera), else the time the read
returned; :attr:`GrabberStats.clock` says which. A consumer sees each drop as a
gap in ``seq``. The grabber measures the real frame rate.

A failed read (``(False, None)``, an empty image, or a :class:`OSError` /
``cv2.error``) of a capture that has not ended yields a gap item (``image`` is
None, ``error`` says why) and a reconnect: the grabber waits (backoff doubling
from ``backoff_s`` up to ``backoff_max_s``), calls ``reopen()`` if the capture
has one, and reads again, each attempt logged; after ``max_reconnects``
failed attempts in a row it gives up and ends with :attr:`GrabberStats.lost`.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import av
import cv2
import numpy as np

from camwhisker.live.capture import DRIVER_CLOCK, READ_CLOCK, capture_time, is_ended

__all__ = ["Grabbed", "GrabberStats", "Grabber", "MODES"]

log = logging.getLogger(__name__)

MODES = ("latest", "every")
#: FIFO length in "every" mode: 4 s at 60 fps, 1280 x 720 x 3 B each (~0.7 GB
#: worst case) is the most a recording may lag its processing before dropping.
EVERY_CAPACITY = 240
#: Reconnect policy: first wait, its cap, and attempts before giving up. A USB
#: camera re-enumerates in ~1-2 s after a replug; 8 attempts doubling from
#: 0.1 s to a 2 s cap wait ~10 s in all.
BACKOFF_S = 0.1
BACKOFF_MAX_S = 2.0
MAX_RECONNECTS = 8
#: Window of the running frame-rate estimate (frames).
FPS_WINDOW = 30


@dataclass(frozen=True)
class Grabbed:
    """One grabbed item. ``image`` None marks a failed read (``error`` says why).

    ``t_s`` is the driver's buffer time where the capture gives it, else
    ``time.monotonic()`` just after the read returned; ``jpeg`` the
    frame's JPEG bytes where the preparation made or kept them (recording)."""

    seq: int
    t_s: float
    image: np.ndarray | None
    error: str = ""
    jpeg: bytes | None = None


@dataclass
class GrabberStats:
    """Counts of a grabber run; ``grabbed`` counts every item, gaps included."""

    mode: str = "latest"
    grabbed: int = 0
    frames: int = 0
    failed_reads: int = 0
    dropped: int = 0
    reconnect_attempts: int = 0
    reconnects: int = 0
    max_depth: int = 0
    lost: bool = False
    ended: bool = False
    fps_measured: float = float("nan")
    first_t_s: float = float("nan")
    last_t_s: float = float("nan")
    errors: list[str] = field(default_factory=list)
    #: Where the frames' t_s came from (capture.DRIVER_CLOCK, READ_CLOCK, or both
    #: joined by " and " where the driver gave times for some frames only).
    clock: str = ""
    driver_times: int = 0


class Grabber:
    """Read ``capture`` in a thread; hand items on by :meth:`get`.

    Parameters
    ----------
    capture : object with ``read()``
        See :mod:`camwhisker.live.capture`.
    mode : "latest" or "every"
    prepare : callable, optional
        ``prepare(image) -> (image, jpeg bytes or None)``, run in the grabber
        thread on each frame (JPEG round trip for a recording).
    max_reconnects, backoff_s, backoff_max_s : reconnect policy.
    capacity : int
        FIFO length in "every" mode.
    """

    def __init__(self, capture, mode: str = "latest",
                 prepare: Callable[[np.ndarray], tuple[np.ndarray, bytes | None]] | None = None,
                 max_reconnects: int = MAX_RECONNECTS, backoff_s: float = BACKOFF_S,
                 backoff_max_s: float = BACKOFF_MAX_S, capacity: int = EVERY_CAPACITY):  # fmt: skip
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        self.capture = capture
        self.mode = mode
        self.prepare = prepare
        self.max_reconnects = max_reconnects
        self.backoff_s = backoff_s
        self.backoff_max_s = backoff_max_s
        self.capacity = 1 if mode == "latest" else capacity
        self.stats = GrabberStats(mode)
        self._queue: collections.deque[Grabbed] = collections.deque()
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._done = False
        self._thread = threading.Thread(target=self._run, name="camwhisker-grabber", daemon=True)
        self._recent: collections.deque[float] = collections.deque(maxlen=FPS_WINDOW)

    # ------------------------------------------------------------- consumer
    def start(self) -> Grabber:
        self._thread.start()
        return self

    def get(self, timeout_s: float | None = None) -> Grabbed | None:
        """The next item; None when the grabber has finished (or on timeout).

        Use :attr:`finished` to tell the two apart.
        """
        with self._cond:
            if not self._queue and not self._done:
                self._cond.wait(timeout_s)
            if self._queue:
                return self._queue.popleft()
            return None

    @property
    def finished(self) -> bool:
        """True when the grabber has stopped and every item has been taken."""
        with self._cond:
            return self._done and not self._queue

    def stop(self, timeout_s: float = 5.0) -> None:
        """Ask the thread to stop and join it (the capture is not released here)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)
        with self._cond:
            self._done = True
            self._cond.notify_all()

    @property
    def pending(self) -> int:
        """Items grabbed and not yet taken."""
        with self._cond:
            return len(self._queue)

    @property
    def fps_now(self) -> float:
        """Frame rate over the last FPS_WINDOW frames (NaN before two)."""
        t = list(self._recent)
        return (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 and t[-1] > t[0] else float("nan")

    # ---------------------------------------------------------------- thread
    def _put(self, item: Grabbed) -> None:
        s = self.stats
        with self._cond:
            if len(self._queue) >= self.capacity:
                if self.mode == "latest":
                    self._queue.popleft()  # the stale one goes
                    self._queue.append(item)
                s.dropped += 1  # "every": the newest goes
            else:
                self._queue.append(item)
            s.max_depth = max(s.max_depth, len(self._queue))
            self._cond.notify()

    def _read(self) -> tuple[np.ndarray | None, str]:
        try:
            ok, image = self.capture.read()
        except (OSError, cv2.error) as exc:
            return None, f"read raised {type(exc).__name__}: {exc}"
        if not ok or image is None or image.size == 0:
            return None, "read returned no frame"
        return image, ""

    def _emit(self, image: np.ndarray | None, error: str, t_s: float) -> None:
        s = self.stats
        jpeg = None
        if image is not None and self.prepare is not None:
            try:
                image, jpeg = self.prepare(image)
            except (ValueError, av.error.FFmpegError, cv2.error) as exc:  # a corrupt JPEG
                image, error = None, f"frame did not decode: {exc}"
                s.failed_reads += 1
        self._put(Grabbed(s.grabbed, t_s, image, error, jpeg))
        s.grabbed += 1

    def _stamp(self, read_s: float) -> float:
        """The frame's time: the driver's where given (:func:`capture_time`), else
        ``read_s``; counted in the stats."""
        s = self.stats
        driver_s = capture_time(self.capture, read_s)
        s.driver_times += driver_s is not None
        clocks = [c for c, n in ((DRIVER_CLOCK, s.driver_times),
                                 (READ_CLOCK, s.frames + 1 - s.driver_times)) if n]  # fmt: skip
        s.clock = " and ".join(clocks)
        return read_s if driver_s is None else driver_s

    def _run(self) -> None:
        s = self.stats
        failures = 0
        try:
            while not self._stop.is_set():
                image, error = self._read()
                t_s = time.monotonic()
                if image is not None:
                    t_s = self._stamp(t_s)
                    if failures:
                        s.reconnects += 1
                        log.warning("capture back after %d failed read(s)", failures)
                    failures = 0
                    s.frames += 1
                    if s.frames == 1:
                        s.first_t_s = t_s
                    s.last_t_s = t_s
                    self._recent.append(t_s)
                    self._emit(image, "", t_s)
                    continue
                if is_ended(self.capture):
                    s.ended = True
                    break
                s.failed_reads += 1
                failures += 1
                if len(s.errors) < 20:
                    s.errors.append(error)
                self._emit(None, error, t_s)
                if failures > self.max_reconnects:
                    s.lost = True
                    log.error("capture lost: %d reconnect attempts failed (%s)",
                              self.max_reconnects, error)  # fmt: skip
                    break
                wait_s = min(self.backoff_s * 2 ** (failures - 1), self.backoff_max_s)
                log.warning("read failed (%s); reconnect attempt %d/%d in %.2f s",
                            error, failures, self.max_reconnects, wait_s)  # fmt: skip
                if self._stop.wait(wait_s):
                    break
                s.reconnect_attempts += 1
                reopen = getattr(self.capture, "reopen", None)
                if reopen is not None and not reopen():
                    log.warning("reconnect attempt %d: reopen failed", failures)
        finally:
            if s.frames > 1 and s.last_t_s > s.first_t_s:
                s.fps_measured = (s.frames - 1) / (s.last_t_s - s.first_t_s)
            with self._cond:
                self._done = True
                self._cond.notify_all()
