"""Camera modes asked for and read back (``live --size WxH --fps F``), on a played file."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import pytest

from camwhisker.cli import main
from camwhisker.live.cameras import C310_PROFILE
from camwhisker.live.capture import CameraCapture, CaptureError

CLIP = Path(__file__).resolve().parents[1] / "sample_frames" / "nominal.mp4"  # 1280x720, 30 fps


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
