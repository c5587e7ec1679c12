"""Capture devices: listing, naming, and the settings profile of a camera.

Listing reads ``/sys/class/video4linux/videoN/`` (``name``, ``index``) and
``/dev/v4l/by-id/`` (stable names: symlinks to ``/dev/videoN``). A UVC camera
makes two nodes, one that captures and one for metadata; the metadata node is
left out. Whether a node captures is asked from the driver
(``VIDIOC_QUERYCAP``'s device capabilities) where the node can be opened, and
otherwise read from sysfs: the UVC driver gives the capture node ``index`` 0
and the metadata node ``index`` 1 (their by-id names end ``-video-index0`` and
``-video-index1``).

A camera is named by index (``0``), by node (``/dev/video2``) or by its
stable name (``/dev/v4l/by-id/usb-046d_0825_...-video-index0``, or the bare
by-id file name). :func:`resolve_camera` turns any of these into the node.

:class:`CameraProfile` is what we ask the camera for (the C310 profile: MJPG,
1280 x 720, 30 fps, white balance and exposure locked). :func:`apply_profile`
sets every property, reads every one back, and warns, listing requested
against applied, where a setting did not take. Many drivers accept a ``set``
and ignore it, so only the read-back counts.
"""

from __future__ import annotations

import errno
import fcntl
import logging
import math
import os
import stat
import struct
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2

__all__ = [
    "CameraInfo",
    "CameraProfile",
    "AppliedSettings",
    "C310_PROFILE",
    "list_cameras",
    "format_camera_list",
    "resolve_camera",
    "parse_querycap",
    "open_node",
    "apply_profile",
    "NO_CAMERA_MESSAGE",
]

log = logging.getLogger(__name__)

SYSFS_V4L = Path("/sys/class/video4linux")
DEV_ROOT = Path("/dev")

#: ``_IOR('V', 0, struct v4l2_capability)``: the capability struct is 104 bytes.
VIDIOC_QUERYCAP = 0x80685600
_CAP_STRUCT = struct.Struct("16s32s32sIII12x")
#: videodev2.h capability bits.
V4L2_CAP_VIDEO_CAPTURE = 0x00000001
V4L2_CAP_VIDEO_CAPTURE_MPLANE = 0x00001000
V4L2_CAP_META_CAPTURE = 0x00800000
V4L2_CAP_DEVICE_CAPS = 0x80000000

NO_CAMERA_MESSAGE = (
    "no capture device found (no /sys/class/video4linux/video* node that captures video); "
    "is a camera plugged in, and is this user in the 'video' group?"
)


@dataclass(frozen=True)
class CameraInfo:
    """One V4L2 node. ``captures`` is False for metadata nodes; ``how`` says
    how that was decided ("querycap" or "sysfs index")."""

    node: str
    index: int
    name: str
    by_id: tuple[str, ...]
    captures: bool
    how: str


def parse_querycap(buf: bytes) -> tuple[str, str, bool]:
    """(driver, card, captures) from a ``struct v4l2_capability``.

    The node's own capabilities (``device_caps``) count where the driver
    fills them (``V4L2_CAP_DEVICE_CAPS``); else those of the whole device.
    """
    driver, card, _bus, _version, caps, device_caps = _CAP_STRUCT.unpack(buf[: _CAP_STRUCT.size])
    node_caps = device_caps if caps & V4L2_CAP_DEVICE_CAPS else caps
    captures = bool(node_caps & (V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_VIDEO_CAPTURE_MPLANE))
    return (driver.split(b"\0")[0].decode(errors="replace"),
            card.split(b"\0")[0].decode(errors="replace"), captures)  # fmt: skip


def open_node(node: str | Path) -> int | None:
    """A file descriptor on the device node, to ask its driver; None where it cannot be
    opened (not a character device, or no permission). The caller closes it."""
    try:
        if not stat.S_ISCHR(os.stat(node).st_mode):
            return None
        return os.open(node, os.O_RDWR | os.O_NONBLOCK)
    except OSError:
        return None


def _querycap(node: Path) -> bool | None:
    """Whether the node captures, from the driver; None where it cannot be asked
    (not a character device, or no permission)."""
    fd = open_node(node)
    if fd is None:
        return None
    try:
        buf = fcntl.ioctl(fd, VIDIOC_QUERYCAP, bytes(_CAP_STRUCT.size))
        return parse_querycap(buf)[2]
    except OSError as exc:
        if exc.errno in (errno.ENOTTY, errno.EINVAL):
            return False  # not a V4L2 node at all
        return None
    finally:
        os.close(fd)


def _read(path: Path) -> str:
    try:
        return path.read_text().strip()
    except OSError:
        return ""


def _by_id(dev_root: Path) -> dict[str, list[str]]:
    """videoN -> its stable names under ``dev_root/v4l/by-id``."""
    out: dict[str, list[str]] = {}
    folder = dev_root / "v4l" / "by-id"
    if not folder.is_dir():
        return out
    for link in sorted(folder.iterdir()):
        try:
            target = os.readlink(link)
        except OSError:
            continue
        out.setdefault(Path(target).name, []).append(str(link))
    return out


def list_cameras(
    sysfs_root: Path = SYSFS_V4L, dev_root: Path = DEV_ROOT, include_metadata: bool = False
) -> list[CameraInfo]:
    """The V4L2 nodes that capture video, in node order.

    Parameters
    ----------
    sysfs_root : Path
        ``/sys/class/video4linux`` (a fake tree in tests).
    dev_root : Path
        ``/dev``: where the nodes and ``v4l/by-id`` live.
    include_metadata : bool
        Keep the nodes that cannot capture too.

    Returns
    -------
    list of CameraInfo
        Empty where there is none (see :data:`NO_CAMERA_MESSAGE`).
    """
    if not Path(sysfs_root).is_dir():
        return []
    ids = _by_id(Path(dev_root))
    found = []
    for entry in Path(sysfs_root).iterdir():
        if not entry.name.startswith("video") or not entry.name[5:].isdigit():
            continue
        node = Path(dev_root) / entry.name
        index_text = _read(entry / "index")
        index = int(index_text) if index_text.isdigit() else 0
        captures = _querycap(node) if node.exists() else None
        how = "querycap"
        if captures is None:
            captures, how = index == 0, "sysfs index"
        info = CameraInfo(str(node), index, _read(entry / "name") or "?",
                          tuple(ids.get(entry.name, ())), captures, how)  # fmt: skip
        if captures or include_metadata:
            found.append(info)
    return sorted(found, key=lambda c: int(Path(c.node).name[5:]))


def format_camera_list(cameras: list[CameraInfo], modes: dict | None = None) -> str:
    """Text for ``camwhisker list-cameras``: one block per camera, or why there is none;
    with ``modes`` (node -> lines of :func:`~camwhisker.live.modes.format_modes`), each
    capturing camera's formats, sizes and frame rates."""
    if not cameras:
        return NO_CAMERA_MESSAGE
    lines = []
    for c in cameras:
        kind = "" if c.captures else "  (metadata, cannot capture)"
        lines.append(f"{c.node}  {c.name}{kind}")
        for name in c.by_id:
            lines.append(f"    stable name: {name}")
        if not c.by_id:
            lines.append("    stable name: none (no /dev/v4l/by-id link)")
        if modes is not None and c.captures:
            lines += modes.get(c.node, [])
    return "\n".join(lines)


def resolve_camera(spec: str | int, dev_root: Path = DEV_ROOT) -> int | str:
    """A camera index, or the ``/dev/videoN`` node that ``spec`` names.

    ``spec`` is an index (``0``), a node, a ``/dev/v4l/by-id`` path, or the
    bare by-id file name. Raises FileNotFoundError for a name that is not there.
    """
    if isinstance(spec, int) or str(spec).isdigit():
        return int(spec)
    path = Path(spec)
    if not path.is_absolute() and "/" not in str(spec):
        path = Path(dev_root) / "v4l" / "by-id" / str(spec)
    if not path.exists() and not path.is_symlink():
        raise FileNotFoundError(f"{spec}: no such camera (see 'camwhisker list-cameras')")
    return str(path.resolve())


# ------------------------------------------------------------------ settings
#: V4L2's exposure_auto menu as OpenCV's V4L2 backend passes it through:
#: 1 = manual exposure, 3 = aperture priority (automatic).
V4L2_EXPOSURE_MANUAL = 1.0
#: A read-back within this of the request counts as applied (OpenCV returns
#: doubles; a driver rounds fps to its nearest interval, 30 -> 30.0).
SETTING_TOLERANCE = 0.5


@dataclass(frozen=True)
class CameraProfile:
    """What to ask the camera for. None leaves a property as the driver has it.

    The defaults are the C310 profile: MJPG (the only format that gives
    1280 x 720 at 30 fps over USB 2), auto white balance off, manual exposure.
    """

    fourcc: str = "MJPG"
    width_px: int = 1280
    height_px: int = 720
    fps: float = 30.0
    auto_wb: float | None = 0.0
    auto_exposure: float | None = V4L2_EXPOSURE_MANUAL
    exposure: float | None = None
    wb_temperature: float | None = None
    #: Frames read and thrown away after opening: the C310 needs ~0.5 s to
    #: settle its sensor after the controls change.
    warmup_frames: int = 15


C310_PROFILE = CameraProfile()

#: Profile field -> OpenCV property, in the order they are set (format first:
#: the size and rate a camera offers depend on it; controls last).
_PROPS = (
    ("fourcc", cv2.CAP_PROP_FOURCC),
    ("width_px", cv2.CAP_PROP_FRAME_WIDTH),
    ("height_px", cv2.CAP_PROP_FRAME_HEIGHT),
    ("fps", cv2.CAP_PROP_FPS),
    ("auto_wb", cv2.CAP_PROP_AUTO_WB),
    ("auto_exposure", cv2.CAP_PROP_AUTO_EXPOSURE),
    ("exposure", cv2.CAP_PROP_EXPOSURE),
    ("wb_temperature", cv2.CAP_PROP_WB_TEMPERATURE),
)


def _fourcc_text(value: float) -> str:
    if not math.isfinite(value) or value <= 0:
        return str(value)
    code = int(value)
    return "".join(chr((code >> (8 * i)) & 0xFF) for i in range(4))


@dataclass
class AppliedSettings:
    """Requested and read-back values of every property, and the mismatches."""

    requested: dict = field(default_factory=dict)
    applied: dict = field(default_factory=dict)
    mismatches: list[str] = field(default_factory=list)
    warmup_discarded: int = 0
    backend: str = ""

    def as_dict(self) -> dict:
        return asdict(self)


def apply_profile(cap, profile: CameraProfile, warn: bool = True) -> AppliedSettings:
    """Set every property of ``profile`` on ``cap``, read all back, report mismatches.

    Parameters
    ----------
    cap : cv2.VideoCapture or an object with ``set(prop, value)`` and ``get(prop)``
    profile : CameraProfile
    warn : bool
        Log one warning listing requested against applied for what did not take.

    Returns
    -------
    AppliedSettings
    """
    out = AppliedSettings()
    if hasattr(cap, "getBackendName"):
        try:
            out.backend = cap.getBackendName()
        except cv2.error:
            out.backend = "?"
    for name, prop in _PROPS:
        want = getattr(profile, name)
        if want is None:
            continue
        value = float(cv2.VideoWriter_fourcc(*want)) if name == "fourcc" else float(want)
        cap.set(prop, value)  # its return value is not trusted: read back below
        out.requested[name] = want
    for name, prop in _PROPS:
        got = float(cap.get(prop))
        out.applied[name] = _fourcc_text(got) if name == "fourcc" else got
        if name not in out.requested:
            continue
        want = out.requested[name]
        if name == "fourcc":
            bad = out.applied[name] != want
        else:
            bad = not (math.isfinite(got) and abs(got - float(want)) <= SETTING_TOLERANCE)
        if bad:
            out.mismatches.append(f"{name}: requested {want}, applied {out.applied[name]}")
    if out.mismatches and warn:
        log.warning("camera settings that did not take (requested vs applied): %s",
                    "; ".join(out.mismatches))  # fmt: skip
    return out
