"""Video files out: uint8 BGR frames to MJPG AVI or H.264 MP4, written atomically.

``.avi`` is Motion-JPEG, what a webcam delivers, written by OpenCV's MJPEG
encoder. ``.mp4`` is H.264 (libx264 through PyAV, 4:4:4 chroma so that colours
survive), what a recording usually is. The file is written to a temporary name
and renamed into place, so a crash never leaves a file that looks whole.
"""

from __future__ import annotations

from collections.abc import Iterable
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np

from camwhisker.files.atomic import atomic_path

__all__ = ["write_video", "VIDEO_SUFFIXES"]

#: The containers :func:`write_video` writes, by file suffix.
VIDEO_SUFFIXES = (".avi", ".mp4")


def write_video(
    path: Path,
    frames: Iterable[np.ndarray],
    fps: float,
    jpeg_quality: int | None = 88,
    h264_crf: int = 18,
) -> int:
    """Write uint8 BGR frames to ``.avi`` (MJPG, at ``jpeg_quality``) or ``.mp4``
    (H.264, at constant rate factor ``h264_crf``); returns the count."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in VIDEO_SUFFIXES:
        raise ValueError(f"{path}: video must end in .avi (MJPG) or .mp4 (H.264)")
    n = 0
    with atomic_path(path) as tmp:
        if suffix == ".avi":
            writer = None
            for frame in frames:
                if writer is None:
                    h, w = frame.shape[:2]
                    writer = cv2.VideoWriter(
                        str(tmp), cv2.CAP_OPENCV_MJPEG, cv2.VideoWriter_fourcc(*"MJPG"), fps, (w, h)
                    )
                    if not writer.isOpened():
                        raise RuntimeError(f"{path}: OpenCV could not open an MJPG writer")
                    writer.set(cv2.VIDEOWRITER_PROP_QUALITY, float(jpeg_quality or 95))
                writer.write(frame)
                n += 1
            if writer is not None:
                writer.release()
        else:
            with av.open(str(tmp), "w", format="mp4") as container:
                stream = None
                for frame in frames:
                    if stream is None:
                        stream = container.add_stream(
                            "libx264", rate=Fraction(fps).limit_denominator(1001)
                        )
                        stream.height, stream.width = frame.shape[:2]
                        stream.pix_fmt = "yuv444p"  # 4:2:0 shifts colours by ~3 DN
                        stream.options = {"crf": str(int(h264_crf)), "preset": "medium"}
                    packet = av.VideoFrame.from_ndarray(frame, format="bgr24")
                    container.mux(stream.encode(packet))
                    n += 1
                if stream is not None:
                    container.mux(stream.encode())
    return n
