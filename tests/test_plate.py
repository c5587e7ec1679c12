"""Forward model: pose -> plate points -> pixels, against hand values and SENSOR.md."""

import math

import numpy as np
import pytest

from camwhisker.plate import (
    Pose,
    cross_arm_edges,
    feature_pixels,
    plate_to_camera,
    rod_ends,
    rotation_cam_from_plate,
    square_corners,
)
from camwhisker.sensor import Sensor

SENSOR = Sensor()


def test_rest_pose_by_hand():
    px = feature_pixels(Pose(), SENSOR)
    half = 2.5 * 1258.79 / 26.5  # square half side at depth z_i + 1.5
    assert px["square_corners"][0] == pytest.approx([639.5 - half, 359.5 - 2.5 * 1234.3 / 26.5])
    assert px["square_corners"][2] == pytest.approx([639.5 + half, 359.5 + 2.5 * 1234.3 / 26.5])
    assert px["tip"] == pytest.approx([639.5, 359.5], abs=1e-12)
    arm = px["cross_arm_edges"][0]  # +x arm end at depth z_i - 1.5
    assert arm[:, 0] == pytest.approx([639.5 + 2 * 1258.79 / 23.5] * 2)


@pytest.mark.parametrize("seed", range(5))
def test_tip_follows_sensor_md_formula(seed):
    rng = np.random.default_rng(seed)
    dz, phi, theta = (
        rng.uniform(0, 1),
        rng.uniform(0, math.radians(35)),
        rng.uniform(-math.pi, math.pi),
    )
    h, z_i = 7.5, 25.0
    tip = plate_to_camera(rod_ends(SENSOR.plate)[1], Pose(dz, phi, theta), SENSOR.plate)
    expected = [
        h * math.sin(phi) * math.cos(theta),
        h * math.sin(phi) * math.sin(theta),
        z_i - dz - h * math.cos(phi),
    ]
    assert tip == pytest.approx(expected, abs=1e-12)


def test_rotation_is_a_pure_tilt():
    rot = rotation_cam_from_plate(math.radians(20), math.radians(-65))
    assert rot @ rot.T == pytest.approx(np.eye(3), abs=1e-14)
    assert np.linalg.det(rot) == pytest.approx(1.0, abs=1e-14)
    # The plate normal tilts by exactly phi; the tilt axis lies in the plate (no twist).
    assert math.degrees(math.acos(rot[2, 2])) == pytest.approx(20.0, abs=1e-9)
    axis = np.array([math.sin(math.radians(-65)), -math.cos(math.radians(-65)), 0.0])
    assert rot @ axis == pytest.approx(axis, abs=1e-14)
    assert rotation_cam_from_plate(0.0, 1.0) == pytest.approx(np.eye(3))


def test_whisker_tilts_opposite_to_tip():
    rot = rotation_cam_from_plate(math.radians(10), math.radians(30))
    whisker = rot @ np.array([0.0, 0.0, 1.0])
    tip = rot @ np.array([0.0, 0.0, -1.0])
    assert np.dot(whisker[:2], tip[:2]) < 0


def test_dz_scales_the_square_as_a_pinhole():
    for dz in (0.0, 0.5, 1.0):
        c = feature_pixels(Pose(dz_mm=dz), SENSOR)["square_corners"]
        assert c[1, 0] - c[0, 0] == pytest.approx(5.0 * 1258.79 / (26.5 - dz), abs=1e-9)


def test_shift_moves_everything_in_the_image_direction():
    rest = feature_pixels(Pose(), SENSOR)["square_corners"]
    moved = feature_pixels(Pose(sx_mm=0.2), SENSOR)["square_corners"]
    assert (moved[:, 0] - rest[:, 0]) == pytest.approx(0.2 * 1258.79 / 26.5)
    assert moved[:, 1] == pytest.approx(rest[:, 1])


def test_feature_shapes():
    assert square_corners(SENSOR.plate).shape == (4, 3)
    assert cross_arm_edges(SENSOR.plate).shape == (4, 2, 3)
    px = feature_pixels(Pose.from_degrees(0.3, 12, 45), SENSOR)
    assert px["cross_outline"].shape == (12, 2) and px["tip"].shape == (2,)
