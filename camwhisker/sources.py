"""Frame sources with timestamps, shared by the batch command and a live loop.

:func:`open_source` gives a :class:`VideoSource` for any file OpenCV can
decode, an :class:`ImageFolderSource` for a folder of images, or a
:class:`SessionSource` for a recorded live session (``SESSION.avi`` with
``SESSION.timestamps.csv`` beside it). Iterating a source yields
:class:`Frame` objects (index, t_s, BGR uint8 image, event) in order.

Timestamps come from the container: PyAV reads every packet's presentation
time without decoding (OpenCV's ``CAP_PROP_POS_MSEC`` is unreliable for
MJPG AVI and variable-rate files). Where the container has none, t_s is
index / fps. A file that ends early (truncated, corrupt) stops the iteration
at the last readable frame and sets :attr:`VideoSource.problem`. A session's
frames carry the live clock, gaps and events (re-zero, re-detect) of its
timestamps file, so processing it again gives the live table.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

__all__ = [
    "Frame", "SourceError", "VideoSource", "ImageFolderSource", "SessionSource", "is_session",
    "open_source", "timestamps_path", "read_timestamps", "TIMESTAMP_COLUMNS", "check_frame_size",
]  # fmt: skip

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
#: Frame rate assumed for an image folder, or a video that states none.
DEFAULT_FPS = 30.0
#: A recorded session's timestamps file: one row per row of the live table.
TIMESTAMP_COLUMNS = ("frame", "video_frame", "seq", "t_s", "event")


class SourceError(ValueError):
    """The input cannot be read as frames (not a video, empty folder, ...)."""


@dataclass(frozen=True)
class Frame:
    """One frame of a source.

    index: 0-based frame number; t_s: time (s); image: ndarray, shape (H, W, 3),
    uint8 BGR, or None where no frame came (a gap in a live session); event:
    "", "rezero", "redetect" or "gap" (see :mod:`camwhisker.stream`).
    """

    index: int
    t_s: float
    image: np.ndarray | None
    event: str = ""


def _container_times(path: Path) -> tuple[np.ndarray | None, float | None, int | None]:
    """Presentation times (s) of the first video stream's packets, sorted; its frame
    rate and stated frame count. (None, None, None) where PyAV cannot read the file."""
    try:
        import av
    except ImportError:  # pragma: no cover - av is a dependency
        return None, None, None
    times = []
    fps = count = None
    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                return None, None, None
            stream = container.streams.video[0]
            rate = stream.average_rate or stream.base_rate
            fps = float(rate) if rate else None
            count = int(stream.frames) or None
            tb = stream.time_base
            start = stream.start_time or 0
            for packet in container.demux(stream):
                if packet.pts is not None and packet.size > 0:
                    times.append(float((packet.pts - start) * tb))
    except (av.error.FFmpegError, ValueError, OSError):
        if not times:
            return None, fps, count
    return (np.sort(np.array(times)) if times else None), fps, count


class VideoSource:
    """Frames of a video file, decoded by OpenCV, timed by the container.

    Parameters
    ----------
    path : str or Path
    decode_threads : int, optional
        Threads FFmpeg may decode with (``cv2.CAP_PROP_N_THREADS``); default:
        OpenCV's choice, all cores. Workers of a parallel batch pass 1, or a
        single worker would already use every core for decoding.

    Raises
    ------
    FileNotFoundError
        No such file.
    SourceError
        OpenCV cannot decode it as video.
    """

    def __init__(self, path: str | Path, decode_threads: int | None = None):
        self.path = Path(path)
        self._params = [] if decode_threads is None else [cv2.CAP_PROP_N_THREADS, decode_threads]
        if not self.path.exists():
            raise FileNotFoundError(f"{self.path}: no such file")
        if self.path.is_dir():
            raise SourceError(f"{self.path}: is a folder, not a video")
        cap = self._capture()
        ok = cap.isOpened()
        first = cap.read()[1] if ok else None
        cap.release()
        if first is None:
            raise SourceError(f"{self.path}: not a video OpenCV can read")
        self.shape = first.shape
        #: (width, height) in px, from the first frame.
        self.frame_size = (first.shape[1], first.shape[0])
        times, fps, count = _container_times(self.path)
        self._times = times
        self.fps = fps or DEFAULT_FPS
        #: Frame count the container states (None if unknown).
        self.expected_frames = count
        #: "container" or "index / fps": where t_s comes from.
        self.time_source = "container" if times is not None else "index / fps"
        #: Why the video ended early, or "" (set after iterating).
        self.problem = ""
        self.frames_read = 0

    def __len__(self) -> int:
        return self.expected_frames or (len(self._times) if self._times is not None else 0)

    def time_of(self, index: int) -> float:
        if self._times is not None and index < len(self._times):
            return float(self._times[index])
        return index / self.fps

    def _capture(self) -> cv2.VideoCapture:
        return cv2.VideoCapture(str(self.path), cv2.CAP_ANY, self._params)

    def __iter__(self) -> Iterator[Frame]:
        cap = self._capture()
        i = 0
        try:
            while True:
                ok, image = cap.read()
                if not ok or image is None:
                    break
                yield Frame(i, self.time_of(i), image)
                i += 1
        finally:
            cap.release()
            self.frames_read = i
            n_times = len(self._times) if self._times is not None else 0
            known = max(self.expected_frames or 0, n_times)
            if known and i < known:
                self.problem = (
                    f"video ended after {i} of {known} frames (truncated or corrupt); "
                    "the readable part was processed"
                )


class ImageFolderSource:
    """Frames from the image files of a folder, in name order, at a given rate.

    Raises
    ------
    SourceError
        The folder holds no image, or an image cannot be read.
    """

    def __init__(self, path: str | Path, fps: float | None = None):
        self.path = Path(path)
        if not self.path.is_dir():
            raise FileNotFoundError(f"{self.path}: no such folder")
        self.files = sorted(p for p in self.path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self.files:
            raise SourceError(f"{self.path}: no images ({', '.join(IMAGE_SUFFIXES)})")
        self.fps = float(fps) if fps else DEFAULT_FPS
        if not math.isfinite(self.fps) or self.fps <= 0:
            raise SourceError(f"fps must be positive, got {fps}")
        first = cv2.imread(str(self.files[0]), cv2.IMREAD_COLOR)
        if first is None:
            raise SourceError(f"{self.files[0]}: cannot read image")
        #: (width, height) in px, from the first image.
        self.frame_size = (first.shape[1], first.shape[0])
        self.time_source = "index / fps"
        self.expected_frames = len(self.files)
        self.problem = ""
        self.frames_read = 0

    def __len__(self) -> int:
        return len(self.files)

    def __iter__(self) -> Iterator[Frame]:
        for i, f in enumerate(self.files):
            image = cv2.imread(str(f), cv2.IMREAD_COLOR)
            if image is None:
                self.problem = f"{f}: cannot read image; stopped after {i} frames"
                return
            self.frames_read = i + 1
            yield Frame(i, i / self.fps, image)


def timestamps_path(video: str | Path) -> Path:
    """``SESSION.timestamps.csv`` beside ``SESSION.avi``."""
    video = Path(video)
    return video.with_name(video.stem + ".timestamps.csv")


def read_timestamps(path: str | Path) -> list[dict]:
    """Rows of a timestamps file: frame, video_frame (int or None), seq, t_s, event."""
    rows = []
    with open(path, newline="") as fh:
        for r in csv.DictReader(fh):
            rows.append({
                "frame": int(r["frame"]),
                "video_frame": int(r["video_frame"]) if r["video_frame"] else None,
                "seq": int(r["seq"]),
                "t_s": float(r["t_s"]) if r["t_s"] else math.nan,
                "event": r["event"],
            })  # fmt: skip
    return rows


class SessionSource:
    """A recorded live session: its video's frames on its own clock, with its gaps and events.

    One :class:`Frame` per row of the timestamps file: the row's t_s and event,
    and the next video frame (decoded as :class:`VideoSource` decodes it), or
    no image where the row is a gap.

    Raises
    ------
    FileNotFoundError
        No video or no timestamps file.
    SourceError
        The video cannot be decoded.
    """

    def __init__(self, video: str | Path, decode_threads: int | None = None):
        self.path = Path(video)
        self.video = VideoSource(self.path, decode_threads)
        self.timestamps = timestamps_path(self.path)
        self.rows = read_timestamps(self.timestamps)
        self.fps = self.video.fps
        self.frame_size = self.video.frame_size
        self.time_source = f"session timestamps ({self.timestamps.name})"
        self.problem = ""

    def __len__(self) -> int:
        return len(self.rows)

    def __iter__(self) -> Iterator[Frame]:
        """The session's rows as frames.

        Raises
        ------
        SourceError
            The timestamps name more frames than the video holds.
        """
        frames = iter(self.video)
        for row in self.rows:
            if row["video_frame"] is None:
                yield Frame(row["frame"], row["t_s"], None, "gap")
                continue
            image = next(frames, None)
            if image is None:
                raise SourceError(f"{self.path}: fewer frames than its timestamps file lists")
            yield Frame(row["frame"], row["t_s"], image.image, row["event"])


def is_session(path: str | Path) -> bool:
    """Whether ``path`` is a recorded live session (a video with its timestamps file)."""
    path = Path(path)
    return path.is_file() and timestamps_path(path).is_file()


def open_source(path: str | Path, fps: float | None = None, decode_threads: int | None = None):
    """A :class:`SessionSource` for a recorded session, a :class:`VideoSource` for another
    file, an :class:`ImageFolderSource` for a folder."""
    path = Path(path)
    if path.is_dir():
        return ImageFolderSource(path, fps)
    if is_session(path):
        return SessionSource(path, decode_threads)
    return VideoSource(path, decode_threads)


def check_frame_size(source, sensor) -> None:
    """Refuse a source whose frames are not the size ``sensor``'s file states.

    Checked once on opening, so that every command names the file and both sizes
    before it processes (or writes) anything.

    Raises
    ------
    SourceError
        The sizes differ.
    """
    width, height = source.frame_size
    cam = sensor.camera
    if (width, height) != (cam.width_px, cam.height_px):
        named = "the default sensor file" if sensor.source == "<defaults>" else sensor.source
        raise SourceError(f"{source.path}: frames are {width}x{height} px but {named} is for "
                          f"{cam.width_px}x{cam.height_px} px; give this camera's sensor file "
                          "with --sensor")
