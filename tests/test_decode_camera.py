"""Camera modes asked for and read back (``live --size WxH --fps F``), and a camera's
MJPG bytes taken raw and decoded by libjpeg-turbo, on played files."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest

from camwhisker.cli import main
from camwhisker.live.cameras import C310_PROFILE
from camwhisker.live.capture import CameraCapture, CaptureError
from camwhisker.live.grabber import Grabber
from camwhisker.live.record import decode_only

CLIP = Path(__file__).resolve().parents[1] / "sample_frames" / "nominal.mp4"  # 1280x720, 30 fps
MJPG = CLIP.with_name("nominal_mjpg.avi")  # 12 frames, 1280x720, MJPG


def _camera(width_px: int, height_px: int, fps: float) -> CameraCapture:
    profile = dataclasses.replace(C310_PROFILE, width_px=width_px, height_px=height_px, fps=fps,
                                  warmup_frames=0)  # fmt: skip
    # A file stands in for the camera: its size and rate are all it "offers".
    return CameraCapture("test-camera", profile, opener=lambda _t: cv2.VideoCapture(str(CLIP)),
                         require_mode=True)  # fmt: skip


def test_a_mode_the_camera_takes_opens_and_is_read_back():
    cam = _camera(1280, 720, 30.0)
    applied = cam.describe()["settings"]["applied"]
    # read back exactly: the file states 1280x720 at 30 fps (tolerance 0.5, a driver's rounding)
    assert (applied["width_px"], applied["height_px"]) == (1280.0, 720.0)
    assert abs(applied["fps"] - 30.0) <= 0.5
    ok, image = cam.read()
    assert ok and image.shape == (720, 1280, 3)
    cam.release()


@pytest.mark.parametrize("mode", [(640, 480, 30.0), (1280, 720, 60.0)])
def test_a_mode_the_camera_refuses_is_one_clear_error(mode):
    with pytest.raises(CaptureError) as err:
        _camera(*mode)
    w, h, fps = mode
    assert (f"camera test-camera: asked for {w}x{h} px at {fps:g} fps, it gives 1280x720 px "
            "at 30 fps") in str(err.value)


@pytest.mark.parametrize("args,why", [
    (["--size", "1280by720"], "--size must be WIDTHxHEIGHT in px"),
    (["--size", "0x720"], "--size must be WIDTHxHEIGHT in px"),
    (["--fps", "-5"], "--fps must be positive"),
])  # fmt: skip
def test_bad_size_or_rate_is_a_usage_error(tmp_path, capsys, args, why):
    code = main(["live", "/dev/video97", "--out", str(tmp_path / "o.csv"), *args])
    assert code == 2 and why in capsys.readouterr().err
    assert not any(tmp_path.iterdir())  # nothing written


class RawCapture:
    """A file that gives its JPEG bytes with CONVERT_RGB off, as V4L2 does for an MJPG
    camera (OpenCV's FFmpeg backend gives them with CAP_PROP_FORMAT -1)."""

    def __init__(self, path):
        self.cap = cv2.VideoCapture(str(path))

    def set(self, prop, value):
        if prop == cv2.CAP_PROP_CONVERT_RGB:
            return self.cap.set(cv2.CAP_PROP_FORMAT, -1.0 if value == 0 else 0.0)
        return self.cap.set(prop, value)

    def get(self, prop):
        if prop == cv2.CAP_PROP_CONVERT_RGB:
            return float(self.cap.get(cv2.CAP_PROP_FORMAT) != -1.0)
        return self.cap.get(prop)

    def __getattr__(self, name):  # isOpened, read, release
        return getattr(self.cap, name)


def _images(opener, warmup: int = 2):
    profile = dataclasses.replace(C310_PROFILE, warmup_frames=warmup)
    cam = CameraCapture("test-camera", profile, opener=opener)
    g = Grabber(cam, "every", decode_only, max_reconnects=0, backoff_s=0.001).start()
    out = []
    while (item := g.get(5.0)) is not None:
        out.append(item.image)
    g.stop()
    assert out[-1] is None  # the file's end: the read that found no frame
    return cam, out[:-1]


def _opencv_decoded(skip: int):
    cap = cv2.VideoCapture(str(MJPG))
    cap.set(cv2.CAP_PROP_FORMAT, -1.0)  # the packets as stored
    packets = [cap.read()[1] for _ in range(12)]
    return [cv2.imdecode(p.reshape(-1), cv2.IMREAD_COLOR) for p in packets[skip:]]


def test_a_cameras_mjpg_bytes_decode_to_opencvs_own_pixels():
    cam, images = _images(lambda _t: RawCapture(MJPG))
    assert cam.describe()["settings"]["applied"]["convert_rgb"] == 0.0 and cam.raw_mjpg
    expected = _opencv_decoded(skip=2)  # the warm-up took two
    assert len(images) == len(expected) == 10
    # libjpeg-turbo through simplejpeg and through cv2.imdecode: the same pixels, exactly
    assert all(np.array_equal(a, b) for a, b in zip(images, expected, strict=True))


def test_a_backend_that_gives_no_jpeg_bytes_is_opened_again_to_decode():
    # OpenCV's FFmpeg backend gives a luma plane with CONVERT_RGB off, not JPEG bytes
    cam, images = _images(lambda _t: cv2.VideoCapture(str(MJPG)))
    assert cam.describe()["settings"]["applied"]["convert_rgb"] == 1.0 and not cam.raw_mjpg
    assert cam.opens == 1  # the failed open is not counted: one camera, opened once
    # opened again from the start: 12 frames less two of warm-up, each decoded whole
    assert len(images) == 10 and all(i.shape == (720, 1280, 3) for i in images)
