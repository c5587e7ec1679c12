"""Camera model: round trips, hand values, degenerate cases."""

import cv2
import numpy as np
import pytest

from camwhisker.sensor.camera import (
    INTRINSIC_NAMES,
    JAC_INTRINSICS,
    JAC_TVEC,
    pixel_rays,
    project,
    project_rigid,
    unproject,
)
from camwhisker.sensor.file import Sensor

PLAIN = Sensor().camera
DISTORTED = (
    Sensor()
    .replace(
        camera={"distortion": [-0.28, 0.11, 0.0012, -0.0009, -0.02], "cx_px": 618.3, "cy_px": 372.8}
    )
    .camera
)


def grid_pixels(cam, step=37):
    v, u = np.mgrid[0 : cam.height_px : step, 0 : cam.width_px : step].astype(float)
    return np.stack([u.ravel() + 0.25, v.ravel() + 0.75], axis=1)


def test_project_by_hand():
    # A point 2 mm right, 1 mm down, 20 mm deep: u = cx + fx * 0.1, v = cy + fy * 0.05.
    uv = project(np.array([2.0, 1.0, 20.0]), PLAIN)
    assert uv == pytest.approx([639.5 + 125.879, 359.5 + 61.715], abs=1e-9)


@pytest.mark.parametrize("cam", [PLAIN, DISTORTED], ids=["pinhole", "distorted"])
def test_unproject_then_project_returns_within_1e9_px(cam):
    uv = grid_pixels(cam)
    xy = unproject(uv, cam)
    assert np.isfinite(xy).all()
    back = project(np.concatenate([xy * 23.0, np.full((len(xy), 1), 23.0)], axis=1), cam)
    assert np.abs(back - uv).max() < 1e-9


@pytest.mark.parametrize("cam", [PLAIN, DISTORTED], ids=["pinhole", "distorted"])
def test_project_then_unproject_returns_the_ray(cam):
    rng = np.random.default_rng(3)
    pts = np.column_stack(
        [rng.uniform(-8, 8, 200), rng.uniform(-5, 5, 200), rng.uniform(15, 30, 200)]
    )
    xy = unproject(project(pts, cam), cam)
    assert np.abs(xy - pts[:, :2] / pts[:, 2:]).max() < 1e-12


def test_points_on_or_behind_the_camera_have_no_image():
    uv = project(np.array([[1.0, 1.0, 0.0], [1.0, 1.0, -5.0], [np.nan, 0, 1], [0, 0, 10.0]]), PLAIN)
    assert np.isnan(uv[:3]).all()
    assert uv[3] == pytest.approx([639.5, 359.5])


def test_strong_distortion_fold_gives_nan_not_a_wrong_ray():
    # k1 = -0.6: the radial map r(1 + k1 r^2) peaks at r = 0.745 (r_d = 0.497) and folds
    # back beyond; pixels farther out than that have no ray.
    cam = Sensor().replace(camera={"distortion": [-0.6, 0.0, 0.0, 0.0, 0.0]}).camera
    r_peak_px = 0.497 * cam.fx_px
    uv = np.array(
        [[cam.cx_px + 0.9 * r_peak_px, cam.cy_px], [cam.cx_px + 1.2 * r_peak_px, cam.cy_px]]
    )
    xy = unproject(uv, cam)
    assert np.isfinite(xy[0]).all()
    assert np.isnan(xy[1]).all()


def test_pixel_rays_match_unproject():
    rays = pixel_rays(DISTORTED)
    assert rays.shape == (720, 1280, 2)
    assert rays[100, 200] == pytest.approx(
        unproject(np.array([200.0, 100.0]), DISTORTED), abs=1e-15
    )


def test_float32_and_float64_agree():
    pts = np.array([[1.5, -0.7, 21.0], [-3.0, 2.0, 26.5]])
    assert np.abs(project(pts.astype(np.float32), PLAIN) - project(pts, PLAIN)).max() < 1e-4


def _object_points():
    rng = np.random.default_rng(5)
    return np.column_stack([rng.uniform(-5, 5, 20), rng.uniform(-4, 4, 20), rng.uniform(-8, 2, 20)])


RVEC = np.array([0.21, -0.33, 0.05])
TVEC = np.array([0.4, -0.3, 24.0])


@pytest.mark.parametrize("cam", [PLAIN, DISTORTED], ids=["pinhole", "distorted"])
def test_project_rigid_is_project_after_the_motion(cam):
    pts = _object_points()
    uv, jac = project_rigid(pts, RVEC, TVEC, cam)
    in_camera = pts @ cv2.Rodrigues(RVEC)[0].T + TVEC
    assert np.abs(uv - project(in_camera, cam)).max() < 1e-9
    assert jac.shape == (2 * len(pts), 15)


@pytest.mark.parametrize("cam", [PLAIN, DISTORTED], ids=["pinhole", "distorted"])
def test_project_rigid_jacobian_columns_by_central_differences(cam):
    pts = _object_points()
    jac = project_rigid(pts, RVEC, TVEC, cam)[1].reshape(len(pts), 2, -1)
    h = 1e-6
    for i in range(3):  # d / d tvec: the same as d / d the point in the camera frame
        e = np.eye(3)[i] * h
        fd = project_rigid(pts, RVEC, TVEC + e, cam)[0] - project_rigid(pts, RVEC, TVEC - e, cam)[0]
        np.testing.assert_allclose(jac[:, :, JAC_TVEC][:, :, i], fd / (2 * h), rtol=0, atol=1e-5)
    for i, name in enumerate(INTRINSIC_NAMES):
        h = 1e-3  # the pixels are linear in every intrinsic
        up = project_rigid(pts, RVEC, TVEC, _moved(cam, name, h))[0]
        down = project_rigid(pts, RVEC, TVEC, _moved(cam, name, -h))[0]
        np.testing.assert_allclose(jac[:, :, JAC_INTRINSICS][:, :, i], (up - down) / (2 * h),
                                   rtol=0, atol=1e-7)  # fmt: skip


def _moved(cam, name, d):
    """The camera with intrinsic ``name`` of INTRINSIC_NAMES moved by d."""
    distortion = ("k1", "k2", "p1", "p2", "k3")
    if name in distortion:
        k = list(cam.distortion)
        k[distortion.index(name)] += d
        return Sensor(camera=cam).replace(camera={"distortion": k}).camera
    return Sensor(camera=cam).replace(camera={name: getattr(cam, name) + d}).camera
