"""Cramér-Rao bound: the method against a hand-computable case, then the scene."""

import math

import numpy as np
import pytest
from scipy.stats import norm

from camwhisker.sensor.file import Sensor
from camwhisker.sim.render.bound import (
    cramer_rao_bound,
    fisher_information,
    nominal_bound_pose,
    pose_bound,
)
from camwhisker.sim.render.render import SceneRenderer
from camwhisker.sim.render.scenarios import NOMINAL_ARTEFACTS


def test_translating_edge_matches_the_closed_form():
    # A step of height A blurred by a Gaussian of sd s, sampled at integer x, in white
    # noise sigma: F = sum (A phi((x - x0)/s) / s)^2 / sigma^2 -> A^2 / (2 sqrt(pi) s sigma^2)
    # (the sum equals the integral to ~1e-10 for s >= 1 px, Poisson summation).
    amp, s, sigma, x0 = 150.0, 1.4, 2.0, 31.3
    x = np.arange(64.0)

    def image(q):
        return amp * norm.cdf((x - q[0]) / s)

    fisher = fisher_information(image, np.array([x0]), np.array([1e-4]), sigma**2)
    bound = cramer_rao_bound(fisher)[0]
    expected = sigma * math.sqrt(2 * math.sqrt(math.pi) * s) / amp
    assert bound == pytest.approx(expected, rel=1e-6)


def test_two_parameters_and_a_singular_case():
    x = np.arange(64.0)

    def image(q):  # edge position and height
        return q[1] * norm.cdf((x - q[0]) / 1.5)

    f = fisher_information(image, np.array([30.0, 100.0]), np.array([1e-4, 1e-3]), 4.0)
    # Cross term: sum (-A phi(u) / s) Phi(u) / sigma^2 = -A / (2 sigma^2), as int phi Phi = 1/2.
    assert f[0, 1] == pytest.approx(-100.0 / (2 * 4.0), rel=1e-6)
    assert f[1, 1] == pytest.approx(np.sum(norm.cdf((x - 30.0) / 1.5) ** 2) / 4.0, rel=1e-6)
    # Two parameters the image cannot tell apart: the bound is infinite, not a number.
    twin = fisher_information(lambda q: image(np.array([q[0] + q[1], 100.0])),
                              np.array([15.0, 15.0]), np.array([1e-4, 1e-4]), 4.0)  # fmt: skip
    assert np.isinf(cramer_rao_bound(twin)).any()


@pytest.fixture(scope="module")
def renderer():
    return SceneRenderer(Sensor())


def test_scene_bound_scales_with_noise(renderer):
    pose = nominal_bound_pose()
    low = pose_bound(renderer.sensor, pose, NOMINAL_ARTEFACTS, renderer=renderer)
    from dataclasses import replace

    high = pose_bound(renderer.sensor, pose, replace(NOMINAL_ARTEFACTS, noise_dn=4.0),
                      renderer=renderer)  # fmt: skip
    for name in low:
        assert 0 < low[name] < high[name]
        # Twice the noise, twice the bound, less the fixed 1/12 DN^2 of 8-bit rounding.
        assert 1.95 < high[name] / low[name] <= 2.0
    # Far below the paper's RMSE (0.22 deg, 0.04 mm): the pixels allow much more.
    assert low["phi_deg"] < 0.01 and low["dz_mm"] < 0.002


def test_unknown_parameter_is_named(renderer):
    with pytest.raises(ValueError, match="'yaw'"):
        pose_bound(renderer.sensor, nominal_bound_pose(), NOMINAL_ARTEFACTS, ("yaw",), renderer)
