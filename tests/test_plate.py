"""Forward model: pose -> plate points -> pixels, against hand values and docs/sensor.md."""

import math

import cv2
import numpy as np
import pytest

from camwhisker.sensor.camera import project, project_rigid
from camwhisker.sensor.file import Sensor
from camwhisker.sensor.plate import (
    Pose,
    corner_edge_directions,
    cross_arm_edges,
    cross_outline,
    end_face_rim,
    feature_pixels,
    in_cross,
    in_square,
    plate_to_camera,
    pose_jacobian,
    q_to_pose,
    rigid_motion,
    rod_ends,
    rod_rims,
    rotation_cam_from_plate,
    square_corners,
)

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


def _q(dz, phi_deg, theta_deg, sx=0.0, sy=0.0):
    p, t = math.radians(phi_deg), math.radians(theta_deg)
    return np.array([dz, p * math.cos(t), p * math.sin(t), sx, sy])


def test_the_motion_as_rotation_vector_is_the_rotation_matrix():
    q = _q(0.3, 24.0, -65.0, 0.1, -0.05)
    rvec, tvec = rigid_motion(q, SENSOR.plate.z_i_mm)
    pose = q_to_pose(q)
    rot = rotation_cam_from_plate(pose.phi_rad, pose.theta_rad)
    assert cv2.Rodrigues(rvec)[0] == pytest.approx(rot, abs=1e-15)
    assert tvec == pytest.approx([0.1, -0.05, 25.0 - 0.3], abs=1e-15)
    assert pose.phi_deg == pytest.approx(24.0) and pose.theta_deg == pytest.approx(-65.0)
    # Both forms project the plate's points to the same pixels.
    pts = np.concatenate([square_corners(SENSOR.plate), cross_outline(SENSOR.plate)])
    a = project_rigid(pts, rvec, tvec, SENSOR.camera)[0]
    b = project(plate_to_camera(pts, pose, SENSOR.plate), SENSOR.camera)
    assert np.abs(a - b).max() < 1e-9


def test_rigid_motion_without_shift():
    rvec, tvec = rigid_motion(np.array([0.2, 0.1, -0.3]), 25.0)
    assert rvec == pytest.approx([-0.3, -0.1, 0.0]) and tvec == pytest.approx([0, 0, 24.8])


def test_pose_jacobian_by_central_differences():
    pts = np.concatenate([square_corners(SENSOR.plate), rod_ends(SENSOR.plate)])
    q = _q(0.5, 18.0, 140.0, 0.05, 0.02)
    z_i = SENSOR.plate.z_i_mm
    jac = pose_jacobian(project_rigid(pts, *rigid_motion(q, z_i), SENSOR.camera)[1])
    jac = jac.reshape(len(pts), 2, 5)
    h = 1e-6
    for i in range(5):
        up, down = q.copy(), q.copy()
        up[i] += h
        down[i] -= h
        fd = (project_rigid(pts, *rigid_motion(up, z_i), SENSOR.camera)[0]
              - project_rigid(pts, *rigid_motion(down, z_i), SENSOR.camera)[0])  # fmt: skip
        np.testing.assert_allclose(jac[:, :, i], fd / (2 * h), rtol=0, atol=1e-5)


def test_rims_lie_on_the_rod():
    plate = SENSOR.plate
    rims = rod_rims(plate)
    assert rims.shape == (48, 3)
    assert np.hypot(rims[:, 0], rims[:, 1]) == pytest.approx(np.full(48, 0.5))
    assert set(rims[:, 2]) == {-1.5, -7.5}
    face = end_face_rim(plate, 64)
    assert face.shape == (64, 3) and (face[:, 2] == -7.5).all()
    assert face.mean(axis=0) == pytest.approx([0.0, 0.0, -7.5], abs=1e-15)


def test_membership_by_hand():
    plate = SENSOR.plate  # square side 5, cross span 4, arm 1.2
    x = np.array([0.0, 2.49, 2.51, 1.9, 1.9, 0.5])
    y = np.array([0.0, -2.49, 0.0, 0.59, 0.61, 1.9])
    assert in_square(x, y, plate).tolist() == [True, True, False, True, True, True]
    assert in_cross(x, y, plate).tolist() == [True, False, False, True, False, True]


def test_corner_edge_directions_run_along_the_features():
    dirs = corner_edge_directions(SENSOR.plate)
    assert dirs.shape == (12, 2, 3)
    sq = square_corners(SENSOR.plate)
    # Top-left corner: edges to the bottom-left and the top-right corners.
    assert dirs[0, 0] == pytest.approx(sq[3] - sq[0]) and dirs[0, 1] == pytest.approx(sq[1] - sq[0])
    # The +x arm's first end corner: along the end edge to its other corner, then inward (-x).
    arm = cross_arm_edges(SENSOR.plate)[0]
    assert dirs[4, 0] == pytest.approx(arm[1] - arm[0]) and dirs[4, 1] == pytest.approx([-1, 0, 0])
