"""One source interface for live and batch input: a camera, a video file, an image folder.

Every capture has the interface of ``cv2.VideoCapture`` that the grabber uses,
so a plain ``cv2.VideoCapture`` is a capture too:

- ``read() -> (ok, image)``: the next frame (uint8 BGR, or a camera's raw
  JPEG bytes as a 1-D uint8 array), or ``(False, None)``;
- ``release()``;

and, where it has them:

- ``reopen() -> bool``: open the device again after a failure;
- ``ended``: True once a file has no more frames (a failed read is then the
  end, not an unplugged camera);
- ``describe() -> dict``: what it is and its applied settings, for the sidecar;
- ``capture_time_s() -> float or None``: the driver's time of the buffer just
  read (:func:`capture_time`).

:class:`CameraCapture` opens a V4L2 camera, applies a :class:`CameraProfile`
and discards warm-up frames, on open and on every reopen.
:class:`SourceCapture` wraps a :mod:`camwhisker.io.sources` source (file or
folder), decoded exactly as batch decodes it.
:class:`~camwhisker.live.playback.PlaybackSource` paces a file at camera rate.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from camwhisker.io.sources import open_source
from camwhisker.live.cameras import (
    C310_PROFILE,
    AppliedSettings,
    CameraProfile,
    apply_profile,
    resolve_camera,
)
from camwhisker.live.record import decode_jpeg, is_jpeg_bytes

__all__ = ["CaptureError", "CameraCapture", "SourceCapture", "open_capture", "is_ended",
           "describe", "capture_time", "DRIVER_CLOCK", "READ_CLOCK"]  # fmt: skip

log = logging.getLogger(__name__)

#: Where a frame's t_s comes from, for the sidecar: the driver's buffer time, or the
#: time the read returned (after OpenCV's decode, its jitter included).
DRIVER_CLOCK = "driver buffer time (CAP_PROP_POS_MSEC, CLOCK_MONOTONIC)"
READ_CLOCK = "time.monotonic() after the read"
#: A driver time this far from the read's monotonic time is on another clock (a file's
#: position, the wall clock of some drivers): not used.
CLOCK_CHECK_S = 1.0
#: A size or rate read back within this of what was asked took (drivers round a rate).
MODE_TOLERANCE = 0.5


@contextlib.contextmanager
def _opencv_quiet():
    """OpenCV's own log silenced while a camera opens (a missing one prints two WARN lines
    before camwhisker's error says the same), unless the user set OPENCV_LOG_LEVEL."""
    if "OPENCV_LOG_LEVEL" in os.environ:
        yield
        return
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        cv2.utils.logging.setLogLevel(level)

class CaptureError(OSError):
    """A capture device cannot be opened or read."""


def is_ended(cap) -> bool:
    """Whether a failed read from ``cap`` means the end of a file.

    A capture with an ``ended`` attribute says so itself; for a plain
    ``cv2.VideoCapture`` on a file the read position has reached the stated
    frame count (a camera states none, so it never ends).
    """
    if hasattr(cap, "ended"):
        return bool(cap.ended)
    if isinstance(cap, cv2.VideoCapture):
        count = cap.get(cv2.CAP_PROP_FRAME_COUNT)
        return count > 0 and cap.get(cv2.CAP_PROP_POS_FRAMES) >= count
    return False


def capture_time(cap, read_s: float) -> float | None:
    """The driver's time (s, ``time.monotonic()``'s clock) of the frame ``cap`` just read,
    where it gives one on that clock: at most :data:`CLOCK_CHECK_S` before ``read_s``,
    the monotonic time the read returned. None otherwise."""
    getter = getattr(cap, "capture_time_s", None)
    t_s = getter() if getter is not None else None
    if t_s is None or not math.isfinite(t_s) or not 0.0 <= read_s - t_s <= CLOCK_CHECK_S:
        return None
    return t_s


def describe(cap) -> dict:
    """What the capture is, for the sidecar."""
    if hasattr(cap, "describe"):
        return cap.describe()
    if isinstance(cap, cv2.VideoCapture):
        return {"kind": "cv2.VideoCapture", "backend": cap.getBackendName(),
                "fps": cap.get(cv2.CAP_PROP_FPS)}  # fmt: skip
    return {"kind": type(cap).__name__}


def _decodes(image: np.ndarray | None) -> bool:
    """Whether a frame read with CONVERT_RGB off is a JPEG's bytes that decode."""
    if image is None or not is_jpeg_bytes(image):
        return False
    try:
        decode_jpeg(image)
    except ValueError:
        return False
    return True


class CameraCapture:
    """A camera with its settings profile applied and read back.

    Parameters
    ----------
    spec : int or str
        Index, ``/dev/videoN``, ``/dev/v4l/by-id/...`` or a bare by-id name.
    profile : CameraProfile
    raw_mjpg : bool
        Where the camera sends MJPG (its format read back), ask OpenCV for its
        JPEG bytes (``CAP_PROP_CONVERT_RGB`` off): they decode by libjpeg-turbo
        (:func:`~camwhisker.live.record.decode_jpeg`, OpenCV's own pixels) in less
        time, and a recording keeps them without re-encoding. Where the warm-up's
        last frame (or one read for the check) is not a JPEG that decodes (a backend
        that does not honour it), the camera is opened again for OpenCV to decode.
        ``settings.applied["convert_rgb"]`` says which (0: the camera's bytes).
    opener : callable, optional
        ``opener(target) -> cv2.VideoCapture``; default opens through V4L2.
        Tests pass one that opens a file.
    require_mode : bool
        The profile's size and frame rate were asked for by the user: where the
        camera's read-back differs, opening fails (a mismatch is otherwise a
        warning).

    Raises
    ------
    CaptureError
        The camera cannot be opened.
    """

    def __init__(
        self,
        spec: int | str,
        profile: CameraProfile = C310_PROFILE,
        raw_mjpg: bool = True,
        opener: Callable[[int | str], cv2.VideoCapture] | None = None,
        require_mode: bool = False,
    ):
        self.spec = spec
        self.require_mode = require_mode
        self.target = resolve_camera(spec) if opener is None else spec
        self.profile = profile
        self.raw_mjpg = raw_mjpg
        self._opener = opener or (lambda t: cv2.VideoCapture(t, cv2.CAP_V4L2))
        self.settings = AppliedSettings()
        self.opens = 0
        self._cap = None
        self._open()

    def _open(self) -> None:
        with _opencv_quiet():
            cap = self._opener(self.target)
        if not cap.isOpened():
            raise CaptureError(f"camera {self.spec}: cannot open {self.target}")
        self.settings = apply_profile(cap, self.profile)
        if self.require_mode:
            self._check_mode(cap)
        raw = self.raw_mjpg and self.settings.applied.get("fourcc") == "MJPG"
        if raw:
            cap.set(cv2.CAP_PROP_CONVERT_RGB, 0.0)
        n, last = 0, None
        for _ in range(self.profile.warmup_frames):
            ok, image = cap.read()
            n, last = n + bool(ok), image if ok else last
        if raw and not _decodes(last if last is not None else cap.read()[1]):
            # Switching back mid-stream is not safe on every backend: open again.
            log.info("camera %s: its frames are not JPEG bytes with CONVERT_RGB off; "
                     "OpenCV decodes them", self.spec)  # fmt: skip
            cap.release()
            self.raw_mjpg = False
            self._open()
            return
        self.settings.applied["convert_rgb"] = float(cap.get(cv2.CAP_PROP_CONVERT_RGB))
        self.settings.warmup_discarded = n
        self._cap = cap
        self.opens += 1

    def _check_mode(self, cap) -> None:
        """Refuse a camera that did not take the size and rate asked for (released)."""
        asked, got = self.settings.requested, self.settings.applied
        keys = ("width_px", "height_px", "fps")
        if all(abs(got[k] - float(asked[k])) <= MODE_TOLERANCE for k in keys):
            return
        cap.release()
        raise CaptureError(
            f"camera {self.spec}: asked for {asked['width_px']}x{asked['height_px']} px at "
            f"{asked['fps']:g} fps, it gives {got['width_px']:g}x{got['height_px']:g} px at "
            f"{got['fps']:g} fps (`v4l2-ctl -d {self.target} --list-formats-ext` lists the "
            "modes it offers)")

    def read(self) -> tuple[bool, np.ndarray | None]:
        if self._cap is None:
            return False, None
        return self._cap.read()

    def capture_time_s(self) -> float | None:
        """The V4L2 buffer's time (s) of the frame just read; None where not given (0)."""
        if self._cap is None:
            return None
        ms = self._cap.get(cv2.CAP_PROP_POS_MSEC)
        return ms / 1e3 if ms > 0 else None

    def reopen(self) -> bool:
        """Release and open again (profile and warm-up included); False if it failed."""
        self.release()
        try:
            self._open()
        except (CaptureError, cv2.error) as exc:
            log.warning("camera %s: reopen failed: %s", self.spec, exc)
            return False
        return True

    @property
    def ended(self) -> bool:
        return False

    def release(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def describe(self) -> dict:
        return {"kind": "camera", "spec": str(self.spec), "device": str(self.target),
                "raw_mjpg": self.raw_mjpg, "opens": self.opens,
                "settings": self.settings.as_dict()}  # fmt: skip


class SourceCapture:
    """A :mod:`camwhisker.io.sources` source (video file or image folder) read frame by frame.

    The frames are decoded exactly as ``camwhisker batch`` decodes them.
    """

    def __init__(self, path: str | Path, fps: float | None = None):
        self.source = open_source(path, fps)
        self.path = Path(path)
        self.fps = self.source.fps
        self._it = iter(self.source)
        self.ended = False
        self.frames_read = 0

    def read(self) -> tuple[bool, np.ndarray | None]:
        if self._it is None:
            return False, None
        try:
            frame = next(self._it)
            while frame.image is None:  # lost in a corrupt stretch: a camera sends none
                frame = next(self._it)
        except StopIteration:
            self.ended = True
            return False, None
        self.frames_read += 1
        return True, frame.image

    def release(self) -> None:
        if self._it is not None:
            self._it.close()
            self._it = None

    def describe(self) -> dict:
        return {"kind": "file", "path": str(self.path), "fps": self.fps,
                "problem": self.source.problem}  # fmt: skip


def _names_camera(spec: str) -> bool:
    return spec.isdigit() or spec.startswith("/dev/") or not Path(spec).exists()


def open_capture(
    spec: str,
    profile: CameraProfile = C310_PROFILE,
    playback_fps: float | None = None,
    fps: float | None = None,
    raw_mjpg: bool = True,
    require_mode: bool = False,
):
    """Open what ``spec`` names: a camera, or a file / folder.

    Parameters
    ----------
    spec : str
        Camera index, node or by-id name; else a video file or image folder.
    profile : CameraProfile
        For a camera.
    playback_fps : float, optional
        Release a file's frames on a real-time clock at this rate
        (:class:`~camwhisker.live.playback.PlaybackSource`); without it a file
        is read as fast as it decodes.
    fps : float, optional
        Frame rate of an image folder.
    require_mode : bool
        For a camera: refuse it where it does not take the profile's size and rate.
    """
    if _names_camera(str(spec)):
        return CameraCapture(spec, profile, raw_mjpg, require_mode=require_mode)
    if playback_fps:
        from camwhisker.live.playback import PlaybackSource

        return PlaybackSource(spec, playback_fps, fps=fps)
    return SourceCapture(spec, fps)
