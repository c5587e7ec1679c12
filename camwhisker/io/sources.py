"""Frame sources with timestamps, shared by the batch command and a live loop.

:func:`open_source` gives a :class:`VideoSource` for any file OpenCV can
decode, an :class:`ImageFolderSource` for a folder of images, or a
:class:`SessionSource` for a recorded live session (``SESSION.avi`` with
``SESSION.timestamps.csv`` beside it). Iterating a source yields
:class:`Frame` objects (index, t_s, BGR uint8 image, event) in order.

Timestamps come from the container: PyAV reads every packet's presentation
time without decoding (OpenCV's ``CAP_PROP_POS_MSEC`` is unreliable for
MJPG AVI and variable-rate files). Where the container has none, t_s is
index / fps. Reading goes on past a corrupt stretch wherever FFmpeg can pick up
after it: each frame lost there is a :class:`Frame` without an image (an
untrusted row downstream), placed by its time. A file that ends early
(truncated) stops the iteration at the last readable frame. Both set
:attr:`VideoSource.problem`, naming the frames. A session's
frames carry the live clock, gaps and events (re-zero, re-detect) of its
timestamps file, so processing it again gives the live table.
"""

from __future__ import annotations

import csv
import math
import re
import sys
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from camwhisker.vision.stream import Frame

__all__ = [
    "SourceError", "VideoSource", "ImageFolderSource", "SessionSource", "is_session",
    "open_source", "timestamps_path", "read_timestamps", "TIMESTAMP_COLUMNS", "check_frame_size",
    "lossy_codec",
]  # fmt: skip

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
#: Video codecs that keep every frame exactly (FFmpeg's names).
LOSSLESS_CODECS = ("ffv1", "png", "rawvideo", "huffyuv", "ffvhuff", "utvideo", "magicyuv")
#: x264's settings in its first frame when it kept every frame (CRF 0 is QP 0).
X264_LOSSLESS = re.compile(rb"rc=cqp .*?\bqp=0\b", re.DOTALL)
#: Frame rate assumed for an image folder, or a video that states none.
DEFAULT_FPS = 30.0
#: A recorded session's timestamps file: one row per row of the live table.
TIMESTAMP_COLUMNS = ("frame", "video_frame", "seq", "t_s", "event")
#: Decoded images a video source keeps for reuse (see :class:`_Buffers`).
REUSED_BUFFERS = 4


class SourceError(ValueError):
    """The input cannot be read as frames (not a video, empty folder, ...)."""


def _container_times(path: Path) -> tuple[np.ndarray | None, float | None, int | None,
                                          np.ndarray]:  # fmt: skip
    """Presentation times (s) of the first video stream's packets, sorted; its frame
    rate and stated frame count; the key frames' times. (None, None, None, empty) where
    PyAV cannot read the file."""
    try:
        import av
    except ImportError:  # pragma: no cover - av is a dependency
        return None, None, None, np.empty(0)
    times, keys = [], []
    fps = count = None
    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                return None, None, None, np.empty(0)
            stream = container.streams.video[0]
            rate = stream.average_rate or stream.base_rate
            fps = float(rate) if rate else None
            count = int(stream.frames) or None
            tb = stream.time_base
            start = stream.start_time or 0
            for packet in container.demux(stream):
                if packet.pts is not None and packet.size > 0:
                    times.append(float((packet.pts - start) * tb))
                    if packet.is_keyframe:
                        keys.append(times[-1])
    except (av.error.FFmpegError, ValueError, OSError):
        if not times:
            return None, fps, count, np.empty(0)
    return (np.sort(np.array(times)) if times else None), fps, count, np.sort(np.array(keys))


class _Buffers:
    """Images for the decoder to write into: one no one else holds any more (by its
    reference count: a frame, a view of it, a rest segment's list), else a fresh one.

    A decoded 720p frame is 2.7 MB: a fresh array each frame costs its page faults
    (~0.2 ms per frame), memory already mapped does not."""

    def __init__(self, keep: int = REUSED_BUFFERS):
        self.keep = keep
        self.pool: list[np.ndarray] = []

    def free(self) -> np.ndarray | None:
        """An image no one else holds, or None (the decoder then allocates one)."""
        for image in self.pool:
            # Held by the pool, this loop and getrefcount's argument alone: free.
            if sys.getrefcount(image) <= 3:
                return image
        return None

    def took(self, image: np.ndarray) -> None:
        """The decoder returned ``image``: kept for reuse, among the last ``keep`` new ones."""
        if not any(image is b for b in self.pool):
            self.pool = [*self.pool, image][-self.keep :]


def _ranges(indices: list[int]) -> str:
    """``[3, 5, 6, 7]`` -> ``"3, 5-7"``."""
    parts, start = [], None
    for k, i in enumerate(indices):
        if start is None:
            start = i
        if k + 1 == len(indices) or indices[k + 1] != i + 1:
            parts.append(f"{start}" if start == i else f"{start}-{i}")
            start = None
    return ", ".join(parts)


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
        times, fps, count, self._key_times = _container_times(self.path)
        self._times = times
        self.fps = fps or DEFAULT_FPS
        #: Frame count the container states (None if unknown).
        self.expected_frames = count
        #: "container" or "index / fps": where t_s comes from.
        self.time_source = "container" if times is not None else "index / fps"
        #: Why the video ended early, or "" (set after iterating).
        self.problem = ""
        self.frames_read = 0
        #: Indices of the frames that could not be decoded (set after iterating).
        self.lost_frames: list[int] = []

    def __len__(self) -> int:
        return self.expected_frames or (len(self._times) if self._times is not None else 0)

    def time_of(self, index: int) -> float:
        if self._times is not None and index < len(self._times):
            return float(self._times[index])
        return index / self.fps

    def _capture(self) -> cv2.VideoCapture:
        return cv2.VideoCapture(str(self.path), cv2.CAP_ANY, self._params)

    def _known(self) -> int:
        """Frames the container holds, as far as it says (0 if it does not)."""
        return max(self.expected_frames or 0, len(self._times) if self._times is not None else 0)

    def _index_of(self, cap: cv2.VideoCapture, floor: int) -> int:
        """The container's index of the frame just read after a failed read, by its time
        (a corrupt stretch drops frames, also some read without a failure); at least
        ``floor``."""
        if self._times is None:
            return floor
        t_s = cap.get(cv2.CAP_PROP_POS_MSEC) / 1e3
        return max(floor, int(np.argmin(np.abs(self._times - t_s))))

    def __iter__(self) -> Iterator[Frame]:
        """The frames in order. Where a read fails before the container's last frame
        (a corrupt stretch), reading goes on; each frame lost is a :class:`Frame`
        without an image (event ``"gap"``), each decoded after it from the broken
        references, up to the next key frame, has event ``"damaged"``, and
        :attr:`problem` names them.

        A failed read is retried while the container says frames remain: FFmpeg
        skips the undecodable packets and picks up after them.
        """
        cap = self._capture()
        known = self._known()
        buffers = _Buffers()
        i = fails = read = 0
        # ended: the reads ran past the container's last frame; broken: a read failed,
        # and from then on frames are placed by their times.
        ended = broken = False
        lost: list[int] = []
        damaged_to = None  # the first key frame after the first lost frame
        try:
            while True:
                ok, image = cap.read(buffers.free())
                if not ok or image is None:
                    fails += 1
                    broken = True
                    if i + fails > known:  # past the last frame the container holds
                        ended = True
                        break
                    continue
                buffers.took(image)
                index = self._index_of(cap, i) if broken else i
                for k in range(i, index):
                    lost.append(k)
                    yield Frame(k, self.time_of(k), None, "gap")
                if lost and damaged_to is None:
                    damaged_to = self._next_key(lost[0]) or math.inf
                damaged = bool(lost) and lost[0] < index < damaged_to
                yield Frame(index, self.time_of(index), image, "damaged" if damaged else "")
                i, fails, read = index + 1, 0, read + 1
        finally:
            cap.release()
            self.frames_read = read
            self.lost_frames = lost
            # A reader that stops early (max frames, a live stop) did not find the end.
            self.problem = self._problems(i, lost, known, ended)

    def _next_key(self, index: int) -> int | None:
        """The first key frame after frame ``index`` (None if none, or no times)."""
        if self._times is None:
            return None
        after = self._key_times[self._key_times > self.time_of(index)]
        return int(np.searchsorted(self._times, after[0])) if after.size else None

    def _problems(self, end: int, lost: list[int], known: int, ended: bool) -> str:
        """What went wrong reading: frames lost mid-file, the file ending early (only
        where the reading ``ended`` there, not where its reader stopped)."""
        out = []
        if lost:
            out.append(f"frames {_ranges(lost)} of {known or end} could not be decoded (a "
                       f"corrupt stretch): their rows are untrusted")
            key = self._next_key(lost[0])
            if end - 1 > lost[0] and (key is None or key > lost[0] + 1):
                upto = f"frame {key - 1}" if key is not None else "the end"
                out.append(f"frames {lost[0] + 1} to {upto} were decoded from damaged "
                           "references (before the next key frame): their rows are untrusted")
        if ended and known and end < known:
            out.append(f"video ended after {end} of {known} frames (truncated or corrupt); "
                       "the readable part was processed")
        return f"{self.path}: " + "; ".join(out) if out else ""


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
        """The images in name order; one that cannot be read, or is not the first one's
        size, is a :class:`Frame` without an image (an untrusted row), named in
        :attr:`problem`, and the folder goes on."""
        bad = []
        self.frames_read, self.problem = 0, ""
        for i, f in enumerate(self.files):
            image = cv2.imread(str(f), cv2.IMREAD_COLOR)
            if image is None or (image.shape[1], image.shape[0]) != self.frame_size:
                why = "cannot read image" if image is None else (
                    f"{image.shape[1]}x{image.shape[0]} px, not "
                    f"{self.frame_size[0]}x{self.frame_size[1]} as the first")
                bad.append(f"{f.name} (frame {i}: {why})")
                self.problem = (f"{self.path}: {len(bad)} image(s) left out, their rows "
                                f"untrusted: {'; '.join(bad)}")
                yield Frame(i, i / self.fps, None, "gap")
                continue
            self.frames_read += 1
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
        if not self.timestamps.is_file():
            raise FileNotFoundError(f"{self.path}: not a recorded session: no "
                                    f"{self.timestamps.name} beside it")
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
            # A frame lost in a corrupt stretch is a gap, as a failed capture read was.
            event = row["event"] if image.image is not None else "gap"
            yield Frame(row["frame"], row["t_s"], image.image, event)


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


def lossy_codec(path: str | Path) -> str:
    """The lossy codec that stored a video or a folder of images ("" where lossless
    or unreadable): "JPEG" for .jpg images, else FFmpeg's name for the video's codec.

    H.264 counts as lossless where x264 wrote it at QP 0 (its settings travel in the
    first frame; another encoder's H.264 counts as lossy)."""
    path = Path(path)
    if path.is_dir():
        jpeg = any(p.suffix.lower() in (".jpg", ".jpeg") for p in path.iterdir())
        return "JPEG" if jpeg else ""
    import av

    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                return ""
            stream = container.streams.video[0]
            name = stream.codec_context.name
            first = next(iter(container.demux(stream)), None) if name == "h264" else None
            settings = b"" if first is None else bytes(first)
    except (av.error.FFmpegError, ValueError, OSError):
        return ""
    if name in LOSSLESS_CODECS or X264_LOSSLESS.search(settings):
        return ""
    return name


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
