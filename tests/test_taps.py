"""Taps in 3-D (camwhisker.sim.mechanics.taps): geometry, truth, theta, files, one trial."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camwhisker.sim.mechanics.taps import (
    Cylinder,
    Plane,
    Sphere,
    TapError,
    protocol_trial,
    simulate_tap,
    tap_on,
    write_taps,
)

TURN = Rotation.from_euler("zyx", (30.0, -25.0, 60.0), degrees=True)
SPHERE = Sphere((40.0, -20.0, 130.0), 100.0)
PLANE_NORMAL = TURN.apply([0.0, 1.0, 0.0])
# The shaft 10 deg off the plate's plane, leaning away from it: its face rises at 80 deg.
SHAFT_TURN = TURN * Rotation.from_euler("x", -10.0, degrees=True)
PLANE = Plane(tuple(PLANE_NORMAL), 25.0)


@pytest.fixture(scope="module")
def sphere_tap():
    tap = tap_on(SPHERE, TURN, np.array([300.0, 200.0, 0.0]), 70.0)
    return tap, simulate_tap(tap, np.random.default_rng(3))


@pytest.fixture(scope="module")
def plane_tap():
    tap = tap_on(PLANE, SHAFT_TURN, np.array([10.0, 80.0, -30.0]), 45.0, mu=0.5)
    return tap, simulate_tap(tap, np.random.default_rng(4))


def test_sphere_first_contact_is_where_the_shaft_touches_the_sphere(sphere_tap):
    tap, _ = sphere_tap
    p0 = tap.origin + 70.0 * tap.a
    c = np.array(SPHERE.center)
    # On the sphere (to rounding), the shaft tangent there: the tap's plane holds the centre.
    assert abs(np.linalg.norm(p0 - c) - SPHERE.radius_mm) < 1e-9
    assert abs(tap.a @ (p0 - c)) < 1e-9
    # The base presses toward the centre, across the shaft.
    assert np.allclose(tap.d, (c - p0) / SPHERE.radius_mm, atol=1e-12)
    assert abs(tap.d @ tap.a) < 1e-12


def test_plane_first_contact_is_on_the_plate_and_its_face_rises_as_the_shaft_leans(plane_tap):
    tap, _ = plane_tap
    p0 = tap.origin + 45.0 * tap.a
    assert abs(PLANE_NORMAL @ p0 - PLANE.distance_mm) < 1e-9
    # 10 deg between shaft and plane: the planar face rises at 80 deg (to rounding).
    assert tap.scene.face_angle_deg == pytest.approx(80.0, abs=1e-9)
    assert tap.d @ PLANE_NORMAL < 0.0  # the base presses into the plate


def test_true_contact_points_lie_on_the_object(sphere_tap, plane_tap):
    _, tr = sphere_tap
    c = tr.contact[np.isfinite(tr.contact).all(axis=1)]
    assert len(c) > 100
    # Between solved 1 mm steps the truth is interpolated along a chord of the great circle:
    # its sag (a few mm of arc on R 100 mm) stays under 0.05 mm.
    gap = np.abs(np.linalg.norm(c - np.array(SPHERE.center), axis=1) - SPHERE.radius_mm)
    assert gap.max() < 0.05
    _, tr = plane_tap
    c = tr.contact[np.isfinite(tr.contact).all(axis=1)]
    assert len(c) > 100
    assert np.abs(c @ PLANE_NORMAL - PLANE.distance_mm).max() < 1e-6  # a line: exact


def test_signals_theta_is_the_tap_direction_in_s(sphere_tap, plane_tap):
    for tap, tr in (sphere_tap, plane_tap):
        d_s = tap.rotation.inv().apply(tap.d)
        assert abs(d_s[2]) < 1e-12  # across the shaft
        want = math.degrees(math.atan2(d_s[1], d_s[0]))
        assert tap.theta_deg == pytest.approx(want, abs=1e-9)
        phi, theta = tr.signals["phi_deg"], tr.signals["theta_deg"]
        use = np.isfinite(theta) & (phi > 5.0)
        assert use.sum() > 50
        err = (theta[use] - want + 180.0) % 360.0 - 180.0
        # Front-end noise 0.05 deg on each tilt component: theta's sigma is 0.05 / phi rad,
        # 0.57 deg at phi 5 deg; the mean over > 50 frames has sigma < 0.08 deg.
        assert abs(err.mean()) < 0.25
        assert np.abs(err).max() < 3.0


def test_pose_log_moves_the_base_along_the_tap_direction_without_turning(sphere_tap):
    tap, tr = sphere_tap
    _, p, q = tr.poses
    step = p - p[0]
    along = step @ tap.d
    assert np.abs(step - np.outer(along, tap.d)).max() < 1e-9
    assert along.max() > 3.0  # pressed past first contact
    assert np.abs(q - q[0]).max() == 0.0
    assert np.allclose(Rotation.from_quat(q[0], scalar_first=True).apply([0, 0, 1]), tap.a)


def test_cylinder_taps_need_the_shaft_across_the_axis():
    cyl = Cylinder((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 50.0)
    with pytest.raises(TapError, match="across"):
        tap_on(cyl, Rotation.identity(), [100.0, 0.0, 0.0], 60.0)  # shaft along the axis
    tap = tap_on(cyl, Rotation.from_euler("y", 90.0, degrees=True), [0.0, 200.0, 7.0], 60.0)
    p0 = tap.origin + 60.0 * tap.a
    assert np.hypot(p0[0], p0[1]) == pytest.approx(50.0, abs=1e-9)
    assert p0[2] == pytest.approx(7.0, abs=1e-9)  # the side facing the target, at its height


def test_write_taps_writes_signals_poses_truth_and_object(sphere_tap, tmp_path):
    _, tr = sphere_tap
    paths = write_taps(tmp_path, SPHERE, [tr], {"seed": 3})
    assert len(paths) == 4
    doc = json.loads((tmp_path / "object.json").read_text())
    assert doc["object"]["model"] == "sphere" and doc["object"]["radius_mm"] == 100.0
    assert doc["taps"][0]["offset_s"] == pytest.approx(tr.run.offset_s)
    head = (tmp_path / "tap.pose.csv").read_text().splitlines()[0]
    assert head == "t_s,x_mm,y_mm,z_mm,qw,qx,qy,qz"


def test_one_sphere_trial_end_to_end():
    from camwhisker.bench.taps import CALIB_PATH, run_trial
    from camwhisker.contact.calibrate import read_calibration

    if not CALIB_PATH.exists():
        pytest.skip("sample_frames/space/calib.toml is not in this checkout")
    trial = protocol_trial(4)  # a tuning seed: the 200 mm sphere at L2, five taps
    assert trial.obj.kind == "sphere" and trial.obj.radius_mm == 100.0
    r = run_trial(4, read_calibration(CALIB_PATH))
    assert r["chosen"] == "sphere"
    # Five taps of ~20 surfels each; GM's bias on the sliding contact is shared by a tap's
    # contacts: 5 mm is about twice the worst tuning-seed error at this radius.
    assert r["center_err_mm"] < 5.0 and r["radius_err_mm"] < 5.0
    assert r["taps_used"] == 5
