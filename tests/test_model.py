"""The tracked points' forward model: its Jacobians against central differences.

Tolerances: OpenCV's analytic derivatives and the chain rule are exact; the
central differences they are checked against carry rounding of ~1e-16 x
600 px / step and truncation of ~step^2, so each comparison allows 1e-6 of
the column's largest entry (and 1e-7 px per unit where a column is ~0).
"""

import dataclasses
import math

import numpy as np
import pytest

from camwhisker.sensor.file import OPTIONAL_PLATE_KEYS, PlateConfig, Sensor
from camwhisker.sensor.model import (
    GEOMETRY_NAMES,
    TIP,
    PlateModel,
    geometry_vector,
    with_geometry,
)

REL_TOL = 1e-6
ABS_TOL = 1e-7
#: Central-difference half-step of the geometry (px, mm, or 1 for distortion): the
#: pixels are linear in the intrinsics, and the centroid's rounding (~1e-11 px)
#: needs a step this large.
GEOMETRY_STEP = 1e-3

PLAIN = Sensor()
DISTORTED = Sensor().replace(
    camera={"distortion": [-0.28, 0.11, 0.0012, -0.0009, -0.02], "cx_px": 618.3, "cy_px": 372.8}
)


def _q(dz, phi_deg, theta_deg, sx=0.0, sy=0.0):
    p, t = math.radians(phi_deg), math.radians(theta_deg)
    return np.array([dz, p * math.cos(t), p * math.sin(t), sx, sy])


def _close(analytic, numeric):
    scale = np.abs(analytic).max()
    assert np.abs(analytic - numeric).max() <= REL_TOL * scale + ABS_TOL


POSES = [_q(0.0, 0.0, 0.0), _q(0.4, 22.0, -130.0, 0.1, -0.2), _q(0.9, 33.0, 60.0)]


@pytest.mark.parametrize("sensor", [PLAIN, DISTORTED], ids=["pinhole", "distorted"])
@pytest.mark.parametrize("q", POSES, ids=["rest", "tilt22", "tilt33"])
def test_geometry_jacobian_matches_central_differences(sensor, q):
    jac = PlateModel(sensor).jacobians(q)
    g0 = geometry_vector(sensor)
    for i in range(len(GEOMETRY_NAMES)):
        h = GEOMETRY_STEP
        up, down = g0.copy(), g0.copy()
        up[i] += h
        down[i] -= h
        uv_up = PlateModel(with_geometry(sensor, up)).project(q, jacobian=False)[0]
        uv_down = PlateModel(with_geometry(sensor, down)).project(q, jacobian=False)[0]
        _close(jac.geometry[:, :, i], (uv_up - uv_down) / (2 * h))


@pytest.mark.parametrize("sensor", [PLAIN, DISTORTED], ids=["pinhole", "distorted"])
@pytest.mark.parametrize("q", POSES[1:], ids=["tilt22", "tilt33"])
def test_exact_pose_jacobian_matches_central_differences(sensor, q):
    m = PlateModel(sensor)
    jac = m.jacobians(q)
    for i in range(5):
        h = 1e-6
        up, down = q.copy(), q.copy()
        up[i] += h
        down[i] -= h
        fd = (m.project(up, jacobian=False)[0] - m.project(down, jacobian=False)[0]) / (2 * h)
        _close(jac.pose[:, :, i], fd)


def test_jacobians_agree_with_the_hot_path():
    m = PlateModel(DISTORTED)
    q = POSES[1]
    uv, jac, _ = m.project(q)
    exact = m.jacobians(q)
    assert np.array_equal(exact.uv, uv)
    assert np.array_equal(exact.pose[:TIP], jac[:TIP])
    # The hot path's tip row is the disc centre's, not the face centroid's.
    gap = np.abs(exact.pose[TIP] - jac[TIP]).max()
    assert 1e-3 < gap < 0.05 * np.abs(jac[TIP]).max()


def test_geometry_names_cover_the_plate_table_and_intrinsics():
    plate_keys = {f"plate.{f.name}" for f in dataclasses.fields(PlateConfig)}
    assert plate_keys <= set(GEOMETRY_NAMES)
    assert {"camera.fx_px", "camera.fy_px", "camera.cx_px", "camera.cy_px", "camera.k1"} <= set(
        GEOMETRY_NAMES
    )
    assert len(set(GEOMETRY_NAMES)) == len(GEOMETRY_NAMES) == 17 + len(OPTIONAL_PLATE_KEYS)


def test_geometry_vector_round_trip():
    g = geometry_vector(DISTORTED)
    assert g.shape == (len(GEOMETRY_NAMES),)
    back = with_geometry(DISTORTED, g)
    assert back.camera == DISTORTED.camera and back.plate == DISTORTED.plate
    moved = g.copy()
    moved[GEOMETRY_NAMES.index("plate.h_r_mm")] = 7.7
    moved[GEOMETRY_NAMES.index("camera.k1")] = -0.1
    s = with_geometry(PLAIN, moved)
    assert s.plate.h_r_mm == 7.7 and s.camera.distortion[0] == -0.1


def test_z_i_moves_the_image_like_dz_the_other_way():
    m = PlateModel(PLAIN)
    jac = m.jacobians(POSES[1])
    dz = jac.pose[:, :, 0]
    z_i = jac.geometry[:, :, GEOMETRY_NAMES.index("plate.z_i_mm")]
    np.testing.assert_allclose(z_i, -dz, rtol=0, atol=1e-9 * np.abs(dz).max())


def test_the_covers_are_the_outlines_rod_and_cross_to_the_bit():
    # The occlusion test projects only the rod and the cross: each point's projection is
    # its own, so they must equal outlines' exactly (0 tolerance: the same arithmetic).
    model = PlateModel(DISTORTED)
    for q in (np.zeros(5), _q(0.4, 25.0, 130.0, 0.1, -0.2)):
        _, rod, cross = model.outlines(q)
        rod_c, cross_c = model.covers(q)
        assert np.array_equal(rod, rod_c) and np.array_equal(cross, cross_c)
