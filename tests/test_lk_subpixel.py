"""The corners' LK has no sub-pixel bias of its own: an analytic blurred corner moved by
exact sub-pixel amounts is found where it went."""

from __future__ import annotations

import numpy as np
import pytest

from camwhisker.bench.subpixel import blurred_corner, lk_bias_curve

SHIFTS_PX = np.round(np.arange(0.0, 1.01, 0.1), 2)


@pytest.mark.parametrize("sigma_px", [1.0, 1.8, 2.6])  # the builds' blur range
@pytest.mark.parametrize("direction", [(1.0, 0.0), (0.6, 0.8)])
@pytest.mark.parametrize("frac", [(0.0, 0.0), (0.3, 0.7), (0.5, 0.5)])
def test_lk_bias_on_a_shifted_corner_is_under_two_hundredths_of_a_pixel(sigma_px, direction,
                                                                        frac):  # fmt: skip
    bias = lk_bias_curve(SHIFTS_PX, direction, sigma_px, frac)
    # Bilinear sampling's peak locking measured at most 0.017 px at 1 px blur (0.011 at
    # 1.8): 0.02 px is 4 % of a 0.1 mm step's 0.5 px move, and a bias the interpolation
    # cannot reach; the codec's, which the steps showed, is 0.1-0.3 px.
    assert np.abs(bias).max() < 0.02
    assert abs(bias[0]) < 1e-4  # no move: the template itself, up to the float32 patch


def test_blurred_corner_is_the_blurred_step_product():
    img = blurred_corner(21, (10.0, 10.0), 1.5)
    # At the corner each step is at its half level: a quarter, to float32 rounding.
    assert img[10, 10] == pytest.approx(0.25, abs=1e-6)
    # Far inside the corner both steps are 1; far outside either one is 0.
    assert img[20, 20] == pytest.approx(1.0, abs=1e-6) and img[0, 20] < 1e-6
