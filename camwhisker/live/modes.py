"""A V4L2 camera's modes: its pixel formats, frame sizes and frame rates, asked of the driver.

Three ioctls of videodev2.h, each enumerated by index until the driver says EINVAL:
``VIDIOC_ENUM_FMT`` (formats), ``VIDIOC_ENUM_FRAMESIZES`` (sizes of a format) and
``VIDIOC_ENUM_FRAMEINTERVALS`` (frame intervals of a size). A size or interval may be a
range (stepwise or continuous) instead of a list: it is given as its bounds. What a mode
delivers is only known once asked for (``live --size WxH --fps F`` reads it back).
"""

from __future__ import annotations

import errno
import fcntl
import os
import struct
from dataclasses import dataclass
from pathlib import Path

from camwhisker.live.cameras import open_node

__all__ = ["CameraMode", "camera_modes", "modes_of_fd", "format_modes", "fourcc_text"]

# _IOWR('V', nr, size) = 3 << 30 | size << 16 | ord('V') << 8 | nr.
VIDIOC_ENUM_FMT = 0xC0405602  # struct v4l2_fmtdesc, 64 bytes
VIDIOC_ENUM_FRAMESIZES = 0xC02C564A  # struct v4l2_frmsizeenum, 44 bytes
VIDIOC_ENUM_FRAMEINTERVALS = 0xC034564B  # struct v4l2_frmivalenum, 52 bytes
V4L2_BUF_TYPE_VIDEO_CAPTURE = 1
#: v4l2_frmsizetypes and v4l2_frmivaltypes.
DISCRETE, CONTINUOUS, STEPWISE = 1, 2, 3

_FMTDESC = struct.Struct("III32sII12x")  # index, type, flags, description, pixelformat, mbus
_FRMSIZE = struct.Struct("III6I8x")  # index, pixel_format, type, discrete (2) | stepwise (6)
_FRMIVAL = struct.Struct("IIIII6I8x")  # index, format, width, height, type, fract(s)
#: No driver lists this many entries of one kind: a bound for a driver that never stops.
_MAX_ENTRIES = 256


@dataclass(frozen=True)
class CameraMode:
    """One format at one size: ``fps`` the frame rates it lists (highest first), or, where
    the driver gives a range, ``fps_range`` its (lowest, highest)."""

    fourcc: str
    description: str
    width: int
    height: int
    fps: tuple[float, ...]
    fps_range: tuple[float, float] | None = None


def fourcc_text(code: int) -> str:
    """A V4L2 pixel format code as its four characters ("MJPG", "YUYV")."""
    return "".join(chr((code >> (8 * k)) & 0xFF) for k in range(4))


def _enumerate(ioctl, fd: int, request: int, pack):
    """The driver's answers to ``request`` for index 0, 1, ... until it says EINVAL."""
    out = []
    for index in range(_MAX_ENTRIES):
        try:
            out.append(ioctl(fd, request, pack(index)))
        except OSError as exc:
            if exc.errno == errno.EINVAL:
                break
            raise
    return out


def _rate(num: int, den: int) -> float:
    """Frames/s of an interval num/den seconds (0 for a zero interval)."""
    return den / num if num else 0.0


def _rates(ioctl, fd: int, code: int, w: int, h: int) -> tuple[tuple[float, ...], tuple | None]:
    answers = _enumerate(ioctl, fd, VIDIOC_ENUM_FRAMEINTERVALS,
                         lambda i: _FRMIVAL.pack(i, code, w, h, 0, 0, 0, 0, 0, 0, 0))
    rates, span = [], None
    for buf in answers:
        _i, _f, _w, _h, kind, *v = _FRMIVAL.unpack(buf[:_FRMIVAL.size])
        if kind == DISCRETE:
            rates.append(round(_rate(v[0], v[1]), 3))
        else:  # min and max intervals: the slowest and fastest rates
            span = (round(_rate(v[2], v[3]), 3), round(_rate(v[0], v[1]), 3))
            break
    return tuple(sorted(set(rates), reverse=True)), span


def _sizes(ioctl, fd: int, code: int) -> list[tuple[int, int]]:
    answers = _enumerate(ioctl, fd, VIDIOC_ENUM_FRAMESIZES,
                         lambda i: _FRMSIZE.pack(i, code, 0, 0, 0, 0, 0, 0, 0))
    sizes = []
    for buf in answers:
        _i, _f, kind, *v = _FRMSIZE.unpack(buf[:_FRMSIZE.size])
        if kind == DISCRETE:
            sizes.append((v[0], v[1]))
        else:  # a range (min_w, max_w, step_w, min_h, max_h, step_h): its two ends
            sizes += [(v[0], v[3]), (v[1], v[4])]
            break
    return sizes


def modes_of_fd(fd: int, ioctl=fcntl.ioctl) -> list[CameraMode]:
    """Every format, size and rate the driver behind ``fd`` lists (``ioctl`` as
    :func:`fcntl.ioctl`; tests pass a fake driver)."""
    modes = []
    formats = _enumerate(ioctl, fd, VIDIOC_ENUM_FMT,
                         lambda i: _FMTDESC.pack(i, V4L2_BUF_TYPE_VIDEO_CAPTURE, 0, b"", 0, 0))
    for buf in formats:
        _i, _t, _flags, desc, code, _mbus = _FMTDESC.unpack(buf[:_FMTDESC.size])
        name = desc.split(b"\0")[0].decode(errors="replace")
        for w, h in _sizes(ioctl, fd, code):
            fps, span = _rates(ioctl, fd, code, w, h)
            modes.append(CameraMode(fourcc_text(code), name, w, h, fps, span))
    return modes


def camera_modes(node: str | Path) -> list[CameraMode] | None:
    """The modes of the camera at ``node`` (``/dev/videoN``); None where the node cannot be
    opened and asked (not a character device, no permission, not a V4L2 node)."""
    fd = open_node(node)
    if fd is None:
        return None
    try:
        return modes_of_fd(fd)
    except OSError:
        return None
    finally:
        os.close(fd)


def format_modes(modes: list[CameraMode] | None, indent: str = "    ") -> list[str]:
    """Lines for ``list-cameras``: one per format and size, its rates."""
    if modes is None:
        return [f"{indent}modes: not readable (the node cannot be opened and asked)"]
    if not modes:
        return [f"{indent}modes: none listed by the driver"]
    lines = []
    for m in modes:
        if m.fps:
            rates = ", ".join(f"{r:g}" for r in m.fps) + " fps"
        elif m.fps_range:
            rates = f"{m.fps_range[0]:g}-{m.fps_range[1]:g} fps"
        else:
            rates = "rates not listed"
        lines.append(f"{indent}{m.fourcc} {m.width}x{m.height}: {rates}  ({m.description})")
    return lines
