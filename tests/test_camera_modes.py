"""A camera's modes asked of the V4L2 driver (camwhisker.live.modes), against a fake driver.

No camera here: the fake answers the three enumeration ioctls as videodev2.h lays out their
structs, for a C310-like camera (YUYV and MJPG at listed sizes and rates) and a camera
that gives ranges. Exact values: the answers are integers and ratios of them.
"""

from __future__ import annotations

import errno

import pytest

from camwhisker.cli import main
from camwhisker.live import modes as M
from camwhisker.live.cameras import format_camera_list, list_cameras

MJPG = int.from_bytes(b"MJPG", "little")
YUYV = int.from_bytes(b"YUYV", "little")
H264 = int.from_bytes(b"H264", "little")


def _iowr(nr: int, size: int) -> int:
    return 3 << 30 | size << 16 | ord("V") << 8 | nr


def test_requests_are_videodev2s():
    # videodev2.h: ENUM_FMT is nr 2, ENUM_FRAMESIZES 74, ENUM_FRAMEINTERVALS 75; the structs
    # are 64, 44 and 52 bytes on every architecture (u32 fields only).
    assert M.VIDIOC_ENUM_FMT == _iowr(2, 64) == _iowr(2, M._FMTDESC.size)
    assert M.VIDIOC_ENUM_FRAMESIZES == _iowr(74, 44) == _iowr(74, M._FRMSIZE.size)
    assert M.VIDIOC_ENUM_FRAMEINTERVALS == _iowr(75, 52) == _iowr(75, M._FRMIVAL.size)
    assert M.fourcc_text(MJPG) == "MJPG"


class FakeDriver:
    """The three ioctls of a camera: ``formats`` (code, description), ``sizes`` per code
    (a list of (w, h), or ("stepwise", min_w, max_w, min_h, max_h)), ``intervals`` per
    (code, w, h) (a list of (num, den), or ("range", min, max) as (num, den) pairs)."""

    def __init__(self, formats, sizes, intervals):
        self.formats, self.sizes, self.intervals = formats, sizes, intervals
        self.calls = 0

    def __call__(self, fd, request, buf):
        self.calls += 1
        if request == M.VIDIOC_ENUM_FMT:
            i, kind, *_ = M._FMTDESC.unpack(buf)
            assert kind == M.V4L2_BUF_TYPE_VIDEO_CAPTURE
            if i >= len(self.formats):
                raise OSError(errno.EINVAL, "no such format")
            code, desc = self.formats[i]
            return M._FMTDESC.pack(i, kind, 0, desc.encode(), code, 0)
        if request == M.VIDIOC_ENUM_FRAMESIZES:
            i, code, *_ = M._FRMSIZE.unpack(buf)
            s = self.sizes[code]
            if s and s[0] == "stepwise":
                if i > 0:
                    raise OSError(errno.EINVAL, "one range")
                _, w0, w1, h0, h1 = s
                return M._FRMSIZE.pack(0, code, M.STEPWISE, w0, w1, 16, h0, h1, 16)
            if i >= len(s):
                raise OSError(errno.EINVAL, "no such size")
            return M._FRMSIZE.pack(i, code, M.DISCRETE, *s[i], 0, 0, 0, 0)
        if request == M.VIDIOC_ENUM_FRAMEINTERVALS:
            i, code, w, h, *_ = M._FRMIVAL.unpack(buf)
            v = self.intervals[(code, w, h)]
            if v and v[0] == "range":
                if i > 0:
                    raise OSError(errno.EINVAL, "one range")
                (n0, d0), (n1, d1) = v[1], v[2]
                return M._FRMIVAL.pack(0, code, w, h, M.CONTINUOUS, n0, d0, n1, d1, 1, d1)
            if i >= len(v):
                raise OSError(errno.EINVAL, "no such interval")
            return M._FRMIVAL.pack(i, code, w, h, M.DISCRETE, *v[i], 0, 0, 0, 0)
        raise OSError(errno.ENOTTY, "not this driver's")


C310 = FakeDriver(
    [(YUYV, "YUYV 4:2:2"), (MJPG, "Motion-JPEG")],
    {YUYV: [(1280, 720)], MJPG: [(1280, 720), (640, 480)]},
    {(YUYV, 1280, 720): [(1, 10), (2, 15)], (MJPG, 1280, 720): [(1, 30), (1, 15)],
     (MJPG, 640, 480): [(1, 30), (1, 60), (1, 30)]})


def test_every_format_size_and_rate_is_listed():
    modes = M.modes_of_fd(3, C310)
    assert [(m.fourcc, m.width, m.height, m.fps) for m in modes] == [
        ("YUYV", 1280, 720, (10.0, 7.5)),
        ("MJPG", 1280, 720, (30.0, 15.0)),
        ("MJPG", 640, 480, (60.0, 30.0)),  # highest first, each rate once
    ]
    assert modes[1].description == "Motion-JPEG" and modes[1].fps_range is None
    text = "\n".join(M.format_modes(modes))
    assert "MJPG 1280x720: 30, 15 fps  (Motion-JPEG)" in text
    assert "YUYV 1280x720: 10, 7.5 fps" in text


def test_ranges_come_as_their_bounds():
    cam = FakeDriver([(H264, "H.264")], {H264: ("stepwise", 160, 1920, 120, 1080)},
                     {(H264, 160, 120): ("range", (1, 120), (1, 5)),
                      (H264, 1920, 1080): [(1001, 30000)]})
    modes = M.modes_of_fd(3, cam)
    assert [(m.width, m.height) for m in modes] == [(160, 120), (1920, 1080)]
    assert modes[0].fps == () and modes[0].fps_range == (5.0, 120.0)
    assert modes[1].fps == (29.97,)  # 30000 / 1001, to the listed 3 decimals
    assert "H264 160x120: 5-120 fps" in "\n".join(M.format_modes(modes))


def test_a_node_that_cannot_be_asked_says_so(tmp_path, capsys):
    plain = tmp_path / "video0"
    plain.write_text("")
    assert M.camera_modes(plain) is None and M.camera_modes(tmp_path / "none") is None
    sysfs = tmp_path / "sys"
    (sysfs / "video0").mkdir(parents=True)
    (sysfs / "video0" / "name").write_text("UVC Camera\n")
    (sysfs / "video0" / "index").write_text("0\n")
    assert main(["list-cameras", "--sysfs", str(sysfs), "--dev", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "modes: not readable" in out
    cams = list_cameras(sysfs, tmp_path)
    text = format_camera_list(cams, {cams[0].node: M.format_modes(M.modes_of_fd(3, C310))})
    assert "    MJPG 640x480: 60, 30 fps" in text


def test_a_driver_error_other_than_the_end_is_not_swallowed():
    def broken(fd, request, buf):
        raise OSError(errno.EIO, "I/O error")

    with pytest.raises(OSError) as caught:  # only EINVAL ends a list
        M.modes_of_fd(3, broken)
    assert caught.value.errno == errno.EIO
