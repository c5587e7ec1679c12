"""Recording a live session so that batch can process it again, bit for bit.

A recording is ``SESSION.avi`` (Motion-JPEG) and ``SESSION.timestamps.csv``
(one row per row of the live table: ``frame, video_frame, seq, t_s, event``).

Identical results need identical pixels. A JPEG decodes differently in
libjpeg (a camera's bytes, :func:`decode_jpeg`) and in FFmpeg (what
``cv2.VideoCapture`` and so batch use on an AVI): up to ~30 DN at colour
edges, from the chroma upsampling. So the live loop processes each frame as
FFmpeg decodes the JPEG bytes that go into the file (:class:`MjpgRoundTrip`,
run in the grabber thread), and the bytes are muxed into the AVI unchanged
(no second encode). A camera's own JPEG bytes (raw MJPG) are kept as they
are; a decoded frame is encoded once at ``jpeg_quality``.
"""

from __future__ import annotations

import csv
import fractions
import math
from collections.abc import Iterator
from pathlib import Path

import av
import cv2
import numpy as np
import simplejpeg

from camwhisker.files.atomic import sync_file, sync_folder
from camwhisker.io.sources import TIMESTAMP_COLUMNS, timestamps_path

__all__ = ["MjpgRoundTrip", "SessionRecorder", "decode_jpeg", "decode_keeping_jpeg",
           "decode_only", "encode_jpeg", "is_jpeg_bytes", "recorded_jpegs", "JPEG_QUALITY",
           "IMAGE_JPEG_QUALITY"]

#: JPEG quality of frames encoded for a recording: 95 keeps the sensor noise
#: (the C310's own MJPG is ~q 85-90), at ~2.5 ms per 720p frame on one core.
JPEG_QUALITY = 95
#: JPEG quality of frames encoded for an MCAP's images where the session has no JPEG bytes
#: (no recording, no raw MJPG): a picture to look at, not to process again.
IMAGE_JPEG_QUALITY = 90


def is_jpeg_bytes(image: np.ndarray) -> bool:
    """Whether a frame read is a JPEG's bytes (uint8, one row), not a decoded image."""
    return image.dtype == np.uint8 and (image.ndim == 1 or (image.ndim == 2 and 1 in image.shape))


def encode_jpeg(image: np.ndarray, quality: int = IMAGE_JPEG_QUALITY) -> bytes:
    """A BGR frame's JPEG bytes at ``quality`` (OpenCV's encoder)."""
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return buf.tobytes()


def decode_jpeg(data: np.ndarray) -> np.ndarray:
    """A camera's JPEG bytes (uint8, shape (N,) or (1, N)) as a BGR image, by
    libjpeg-turbo through simplejpeg: the pixels ``cv2.imdecode`` (and OpenCV's own
    camera path) gives, with the same accurate DCT and chroma upsampling, in less time.

    Raises
    ------
    ValueError
        Not a whole JPEG (libjpeg's reason: truncated, corrupt).
    """
    try:
        return simplejpeg.decode_jpeg(data.reshape(-1), colorspace="BGR")
    except ValueError as exc:
        raise ValueError(f"the JPEG frame did not decode: {exc}") from None


class MjpgRoundTrip:
    """``prepare(image) -> (FFmpeg-decoded BGR image, JPEG bytes)`` for the grabber.

    ``image`` is a BGR frame (encoded here) or a camera's JPEG bytes (kept).
    """

    def __init__(self, jpeg_quality: int = JPEG_QUALITY):
        self.jpeg_quality = int(jpeg_quality)
        self._ctx = av.CodecContext.create("mjpeg", "r")
        self._ctx.thread_count = 1

    def __call__(self, image: np.ndarray) -> tuple[np.ndarray, bytes]:
        data = image.tobytes() if is_jpeg_bytes(image) else encode_jpeg(image, self.jpeg_quality)
        frames = self._ctx.decode(av.Packet(data))
        if not frames:
            raise ValueError("the JPEG frame did not decode")
        return frames[0].to_ndarray(format="bgr24"), data


def decode_only(image: np.ndarray) -> tuple[np.ndarray, None]:
    """``prepare`` without a recording: a camera's JPEG bytes are decoded, BGR passes."""
    if is_jpeg_bytes(image):
        return decode_jpeg(image), None
    return image, None


def decode_keeping_jpeg(image: np.ndarray) -> tuple[np.ndarray, bytes | None]:
    """``prepare`` for an MCAP without a recording: the frame as :func:`decode_only` gives
    it (the same pixels as without the MCAP), with a camera's own JPEG bytes (raw MJPG) as
    sent; a decoded frame has none here, the bag's thread encodes it (:func:`encode_jpeg`)
    off the frame's way to its row."""
    if is_jpeg_bytes(image):
        return decode_only(image)[0], image.tobytes()
    return image, None


def recorded_jpegs(video: str | Path) -> Iterator[bytes]:
    """The JPEG bytes of a recording's frames as muxed, in order (the k-th is its
    timestamps' video_frame k); the container is closed when the iterator is."""
    with av.open(str(video)) as container:
        for packet in container.demux(video=0):
            if packet.size:  # the demuxer's last, empty packet flushes: not a frame
                yield bytes(packet)


class SessionRecorder:
    """Writes ``SESSION.avi`` (the JPEG bytes, muxed as they are) and its timestamps.

    The timestamps file is flushed row by row; the AVI is finalised by
    :meth:`close` (a killed process leaves an AVI without its index, which
    FFmpeg still reads).

    Parameters
    ----------
    video : Path
        Must end in ``.avi``.
    rate_fps : float
        Nominal rate stored in the container (the real times are in the
        timestamps file).
    """

    def __init__(self, video: Path, rate_fps: float):
        self.video = Path(video)
        if self.video.suffix.lower() != ".avi":
            raise ValueError(f"{self.video}: a recording must be .avi (MJPG)")
        self.video.parent.mkdir(parents=True, exist_ok=True)
        self.timestamps = timestamps_path(self.video)
        self.rate = fractions.Fraction(round(rate_fps * 1000), 1000)
        self._container = av.open(str(self.video), "w", format="avi")
        self._stream = None
        self._ts = open(self.timestamps, "w", newline="")  # noqa: SIM115 - closed in close()
        self._csv = csv.writer(self._ts)
        self._csv.writerow(TIMESTAMP_COLUMNS)
        self.frames = 0
        self.closed = False

    def write(self, frame: int, seq: int, t_s: float, jpeg: bytes | None,
              shape: tuple[int, ...] | None, event: str = "") -> None:  # fmt: skip
        """One row of the session: a frame (``jpeg`` given) or a gap (``jpeg`` None)."""
        video_frame = ""
        if jpeg is not None:
            if self._stream is None:
                self._stream = self._container.add_stream("mjpeg", rate=self.rate)
                self._stream.height, self._stream.width = shape[:2]
                self._stream.pix_fmt = "yuvj420p"
            packet = av.Packet(jpeg)
            packet.stream = self._stream
            packet.pts = packet.dts = self.frames
            packet.time_base = 1 / self.rate
            self._container.mux(packet)
            video_frame = self.frames
            self.frames += 1
        t = "" if t_s is None or not math.isfinite(t_s) else format(t_s, ".6f")
        self._csv.writerow([frame, video_frame, seq, t, event])
        self._ts.flush()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self._ts.close()
        self._container.close()
        # Streamed under their names (a killed session keeps them): on the disk at the end.
        for path in (self.timestamps, self.video):
            sync_file(path)
        sync_folder(self.video.parent)

