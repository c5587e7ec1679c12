"""calibrate-sensor: the bundle adjustment of a build's geometry.

The build is the nominal sensor off by a fixed deviation of SENSOR.md
section 8's size (fx +3 %, cx/cy 8 px, k1 -0.06, z_i +0.6 mm, h_r -0.2 mm,
feature sizes +2 %). On exact model points with 0.05 px noise the fit must
land within 3 SE of the truth, and each SE must be well inside the build's
tolerance (else the fit would tell nothing).
"""

from __future__ import annotations

import numpy as np
import pytest

from camwhisker.geometry.adjust import SE_LIMIT, adjust_geometry, tolerances
from camwhisker.model import GEOMETRY_NAMES, PlateModel, geometry_vector
from camwhisker.sensor import Sensor

NOISE_PX = 0.05
N_REST = 10


def deviated_build(nominal: Sensor) -> Sensor:
    """The issue's example build: a fixed deviation, no random drawing."""
    cam, plate = nominal.camera, nominal.plate
    return nominal.replace(
        camera={"fx_px": cam.fx_px * 1.03, "cx_px": cam.cx_px + 8.0, "cy_px": cam.cy_px - 8.0,
                "distortion": [-0.06, 0.0, 0.0, 0.0, 0.0]},
        plate={"z_i_mm": plate.z_i_mm + 0.6, "h_r_mm": plate.h_r_mm - 0.2,
               **{k: getattr(plate, k) * 1.02 for k in
                  ("square_side_mm", "cross_span_mm", "cross_arm_mm", "rod_diameter_mm")}},
    )  # fmt: skip


def sweep_poses(n: int, phi_max_deg: float = 30.0) -> np.ndarray:
    """Rest frames, then a tilt sweeping all directions up to phi_max, shape (n, 5)."""
    s = np.linspace(0.0, 1.0, n - N_REST)
    phi = np.radians(phi_max_deg) * np.sin(np.pi * s) ** 2
    theta = np.radians(540.0) * s
    dz = 0.8 * np.sin(3.0 * s) ** 2
    q = np.zeros((n, 5))
    q[N_REST:, 0], q[N_REST:, 1], q[N_REST:, 2] = dz, phi * np.cos(theta), phi * np.sin(theta)
    return q


def model_points(sensor: Sensor, q: np.ndarray, seed: int) -> np.ndarray:
    model = PlateModel(sensor)
    pts = np.array([model.project(qq, jacobian=False)[0] for qq in q])
    return pts + np.random.default_rng(seed).normal(0.0, NOISE_PX, pts.shape)


@pytest.fixture(scope="module")
def build():
    return deviated_build(Sensor())


@pytest.fixture(scope="module")
def fitted(build):
    q = sweep_poses(90)
    pts = model_points(build, q, seed=3)
    pts[30:34, 5] = np.nan  # an occluded corner
    pts[50, 2] += 6.0  # a mistracked one: the robust loss must shrug it off
    rest = np.arange(len(q)) < N_REST
    side = {"plate.square_side_mm": build.plate.square_side_mm}
    return adjust_geometry(pts, Sensor(), rest, fixed=side), q


def test_adjustment_recovers_the_build_within_3_se(build, fitted):
    adj, _ = fitted
    truth = geometry_vector(build)
    free = np.isfinite(adj.se)
    assert free.sum() >= 10
    for name in ("camera.fx_px", "camera.cx_px", "camera.k1", "plate.z_i_mm", "plate.h_r_mm",
                 "plate.cross_span_mm"):  # fmt: skip
        assert name not in adj.held, name
    z = (adj.value[free] - truth[free]) / adj.se[free]
    assert np.all(np.abs(z) < 3.0), dict(
        zip(np.array(GEOMETRY_NAMES)[free], z.round(2), strict=True)
    )
    tol = tolerances(Sensor())
    assert np.all(adj.se[free] < SE_LIMIT * tol[free])
    assert adj.se[GEOMETRY_NAMES.index("plate.z_i_mm")] < 0.1
    # What is held is held at nominal, and the known length at its value.
    assert adj.held["plate.square_side_mm"] == "held at the given value"
    assert adj.value[GEOMETRY_NAMES.index("plate.square_side_mm")] == build.plate.square_side_mm
    for name in adj.held:
        if name != "plate.square_side_mm":
            i = GEOMETRY_NAMES.index(name)
            assert adj.value[i] == adj.nominal[i]


def test_adjustment_recovers_poses_and_residuals(fitted):
    adj, q = fitted
    phi_err = np.degrees(np.hypot(adj.q[:, 1], adj.q[:, 2]) - np.hypot(q[:, 1], q[:, 2]))
    assert np.abs(phi_err).max() < 0.02
    assert np.abs(adj.q[:, 0] - q[:, 0]).max() < 0.01
    assert np.all(adj.q[:N_REST] == 0.0)
    # The mistracked corner still adds its Huber share to the robust variance.
    assert adj.sigma_px == pytest.approx(NOISE_PX, rel=0.5)
    per_point = adj.rms_per_point_px()
    assert per_point.shape == (13,) and np.all(per_point[[0, 1, 3, 4]] < 2 * NOISE_PX)
    assert adj.rms_per_frame_px()[50] > 1.0  # the mistracked corner shows in its frame
    assert adj.phi_max_deg == pytest.approx(30.0, abs=0.1)
    assert not any("tilt" in w for w in adj.warnings)


def test_without_a_known_length_the_scale_is_held_and_flagged(build):
    q = sweep_poses(60)
    adj = adjust_geometry(model_points(build, q, seed=4), Sensor(), np.arange(60) < N_REST)
    lengths = [n for n in GEOMETRY_NAMES if n.endswith("_mm")]
    assert any(n in adj.held and "not determined" in adj.held[n] for n in lengths)
    assert any("no known length" in w for w in adj.warnings)


def test_a_small_sweep_is_warned_about(build):
    q = sweep_poses(40, phi_max_deg=8.0)
    adj = adjust_geometry(
        model_points(build, q, seed=5),
        Sensor(),
        np.arange(40) < N_REST,
        fixed={"plate.square_side_mm": build.plate.square_side_mm},
    )
    assert any("largest tilt" in w for w in adj.warnings)


def test_bad_inputs_are_named():
    pts = np.zeros((5, 13, 2))
    with pytest.raises(ValueError, match="rest"):
        adjust_geometry(pts, Sensor(), np.zeros(5, bool))
    with pytest.raises(ValueError, match="unknown geometry"):
        adjust_geometry(pts, Sensor(), np.ones(5, bool), fixed={"plate.nope": 1.0})
    with pytest.raises(ValueError, match="points_uv"):
        adjust_geometry(pts[:, :12], Sensor(), np.ones(5, bool))
