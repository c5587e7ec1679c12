"""The calibration's error by its source (camwhisker.bench.systematics), on model points."""

from __future__ import annotations

import numpy as np
import pytest

from camwhisker.bench.systematics import GROUPS, refit_with_true_points, tilt_coefficients
from camwhisker.calibration.adjust import adjust_geometry, bias_terms
from camwhisker.calibration.sweep import SensorFit, TrackedSweep
from camwhisker.sensor.file import OPTIONAL_PLATE_KEYS, Sensor
from camwhisker.sensor.model import TIP, PlateModel, geometry_vector
from camwhisker.vision.mismatch import phi_response
from tests.test_calibrate_sensor import (
    N_REST,
    NOISE_PX,
    deviated_build,
    model_points,
    sweep_poses,
)

#: Tilt-term coefficient given to the square's corners (px): the size of the largest
#: ones on the reality suite's sweeps.
SQUARE_TILT_PX = 0.15
#: The true points' white noise: the model points' own (px), for each of the 13.
NOISE = np.full(TIP + 1, NOISE_PX)


def test_tilt_coefficients_recover_known_terms():
    q = sweep_poses(90)
    rng = np.random.default_rng(4)
    coef = rng.normal(0.0, 0.1, (TIP + 1, 2, 3))
    terms = np.array([bias_terms(qq[:3]) for qq in q])
    error = np.einsum("fk,jck->fjc", terms, coef) + 0.2 * q[:, :1, None] + 0.5
    error += rng.normal(0.0, 0.02, error.shape)
    error[40:50, 3] = np.nan  # a corner lost for a while
    got, scatter = tilt_coefficients(error, q)
    # Each coefficient within 4 of its SEs (noise 0.02 px; the sweep's dz follows the
    # tilt, so the phi^2 term's SE is ~0.015 px, the others' ~0.003).
    design = np.column_stack([terms, q[:, 0], np.ones(len(q))])
    se = 0.02 * np.sqrt(np.diag(np.linalg.inv(design.T @ design))[:3])
    # (1.1: corner 3's frames are fewer.)
    assert np.all(np.abs(got - coef) < 4 * 1.1 * se), (np.abs(got - coef) / se).max()
    assert scatter == pytest.approx(np.full(scatter.shape, 0.02), rel=0.35)


@pytest.fixture(scope="module")
def biased():
    """A sweep whose square's corners carry a tilt-dependent error, its adjustment as a
    calibration's last round, and the exact points."""
    build = deviated_build(Sensor())
    q = sweep_poses(90)
    exact = np.array([PlateModel(build).project(qq, jacobian=False)[0] for qq in q])
    pts = model_points(build, q, seed=5)
    terms = np.array([bias_terms(qq[:3]) for qq in q])
    pts[:, :4] += SQUARE_TILT_PX * np.einsum("fk,jck->fjc", terms,
                                             np.random.default_rng(6).choice([-1, 1], (4, 2, 3)))
    rest = np.arange(len(q)) < N_REST
    fixed = {"plate.square_side_mm": build.plate.square_side_mm,
             "plate.rod_diameter_mm": build.plate.rod_diameter_mm,
             **{f"plate.{k}": 0.0 for k in OPTIONAL_PLATE_KEYS}}  # fmt: skip
    adj = adjust_geometry(pts, Sensor(), rest, fixed=fixed, q0=q, corner_shifts=True)
    n = len(q)
    tracked = TrackedSweep(pts, q, np.ones(n, bool), rest, np.zeros(n, int), np.arange(n) / 30,
                           np.full((1, TIP, 2), np.nan))  # fmt: skip
    return build, SensorFit(adj, tracked), exact


def _phi_error_deg(sensor: Sensor, build: Sensor) -> float:
    """The file's phi error at 20 deg against the build's (linearised, worst direction)."""
    d = geometry_vector(sensor) - geometry_vector(build)
    return float(np.abs(phi_response(PlateModel(build)) @ d).max())


def test_true_points_for_the_biased_group_take_out_its_error(biased):
    build, cal, exact = biased
    as_tracked = _phi_error_deg(cal.sensor, build)
    square, tip = (_phi_error_deg(refit_with_true_points(cal, Sensor(), exact, GROUPS[g][0],
                                                         NOISE), build)
                   for g in ("square", "tip"))  # fmt: skip
    print(f"phi error at 20 deg: as tracked {as_tracked:.4f}, square true {square:.4f}, "
          f"tip true {tip:.4f} deg")  # fmt: skip
    # The square's error moves the fit (here 0.009 deg, the size of a quiet build's whole
    # phi RMSE); with its points true, about what the 0.05 px of noise leaves (0.003),
    # while true points for an unbiased group change little (0.008).
    assert as_tracked > 0.006
    assert square < 0.5 * as_tracked
    assert tip > 0.6 * as_tracked
