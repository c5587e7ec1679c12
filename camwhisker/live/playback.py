"""A video file played back at camera rate: a stand-in for a camera in tests and demos.

:class:`PlaybackSource` decodes a file (as batch decodes it) and releases frame
k at ``t0 + k / fps`` on the monotonic clock, whatever the file's own rate:
``read()`` sleeps until the frame is due. Like a camera's driver queue it
never waits for its reader; a reader that falls behind gets frames that are
already due at once (stale), which is what the grabber's "latest" mode is for.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from camwhisker.live.capture import SourceCapture

__all__ = ["PlaybackSource"]


class PlaybackSource:
    """Frames of a file released on a real-time clock.

    Parameters
    ----------
    path : str or Path
        Video file or image folder.
    rate_fps : float
        Release rate (30, 60, 120, ...), independent of the file's rate.
    loop : bool
        Start again at the end (for demos); a looped file never ends.
    fps : float, optional
        Frame rate of an image folder (only its timestamps; pacing uses rate_fps).
    clock : callable
        Monotonic seconds (injectable for tests).
    """

    def __init__(self, path: str | Path, rate_fps: float, loop: bool = False,
                 fps: float | None = None, clock=time.monotonic):  # fmt: skip
        if not (math.isfinite(rate_fps) and rate_fps > 0):
            raise ValueError(f"rate_fps must be positive, got {rate_fps}")
        self.path = Path(path)
        self.rate_fps = float(rate_fps)
        self.loop = loop
        self._fps = fps
        self._clock = clock
        self._src = SourceCapture(self.path, fps)
        #: Clock time (s) at which frame 0 was released; frame k is released at
        #: ``t0_s + k / rate_fps`` or later (None before the first read).
        self.t0_s: float | None = None
        self._k = 0
        self.released = 0
        self.late = 0

    @property
    def source(self):
        """The file's :mod:`camwhisker.io.sources` source (its frame size, its problem)."""
        return self._src.source

    @property
    def ended(self) -> bool:
        return self._src.ended and not self.loop

    def read(self) -> tuple[bool, np.ndarray | None]:
        ok, image = self._src.read()
        if not ok and self.loop and self._src.ended:
            self._src.release()
            self._src = SourceCapture(self.path, self._fps)
            ok, image = self._src.read()
        if not ok:
            return False, None
        now = self._clock()
        if self.t0_s is None:
            self.t0_s = now
        due = self.t0_s + self._k / self.rate_fps
        if due > now:
            time.sleep(due - now)
        elif now - due > 1.0 / self.rate_fps:
            self.late += 1  # the reader fell more than a frame behind the clock
        self._k += 1
        self.released += 1
        return True, image

    def reopen(self) -> bool:
        """A file does not unplug: nothing to do."""
        return True

    def release(self) -> None:
        self._src.release()

    def describe(self) -> dict:
        return {"kind": "playback", "path": str(self.path), "rate_fps": self.rate_fps,
                "loop": self.loop, "released": self.released,
                "late_by_over_a_period": int(self.late)}  # fmt: skip
