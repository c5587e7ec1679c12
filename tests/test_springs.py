"""The spring model (camwhisker.sensor.springs) against hand-worked beam cases.

Tolerances: a grillage beam element is exact for end loads, so the chain's
stiffness matches the closed forms to rounding (1e-9 relative); Roark's
torsion constant is good to 0.5 % (its stated accuracy) against the series.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from camwhisker.sensor.springs import (
    SpringDesign,
    SpringDesignError,
    end_stiffness,
    rect_torsion_constant,
    serpentine_centreline,
    suspension_stiffness,
)

EI, GJ = 84.375, 52.04  # Table I's beam in acrylic (N mm^2), for round numbers
EXACT = 1e-9


def _free_end_compliance(nodes):
    """Tip deflection per unit tip force with the tip free to turn: inv(K)[0, 0]."""
    return np.linalg.inv(end_stiffness(nodes, EI, GJ))[0, 0]


@pytest.mark.parametrize(("a", "b", "series"), [(1.0, 1.0, 0.1406), (2.0, 1.0, 0.2287 * 2.0)])
def test_torsion_constant_against_the_series(a, b, series):
    # Timoshenko & Goodier's series: J = beta a b^3, beta 0.1406 (square), 0.2287 (2:1).
    assert rect_torsion_constant(a, b) == pytest.approx(series, rel=5e-3)
    assert rect_torsion_constant(b, a) == rect_torsion_constant(a, b)


def test_straight_cantilever():
    length = 7.0
    nodes = [(length, 0.0), (0.0, 0.0)]  # the free end first, clamped at the origin
    k = end_stiffness(nodes, EI, GJ)
    # Tip free to turn: 3 EI / L^3; tip held level (guided): 12 EI / L^3.
    assert 1.0 / _free_end_compliance(nodes) == pytest.approx(3 * EI / length**3, rel=EXACT)
    assert k[0, 0] == pytest.approx(12 * EI / length**3, rel=EXACT)


def test_l_shaped_cantilever_bends_and_twists():
    # Clamped at the origin, leg a along x, leg b along y, a tip load P along z:
    # delta / P = a^3 / 3EI + b^3 / 3EI + b^2 a / GJ (leg a twisted by P b).
    a, b = 5.0, 3.0
    nodes = [(a, b), (a, 0.0), (0.0, 0.0)]
    expected = a**3 / (3 * EI) + b**3 / (3 * EI) + b**2 * a / GJ
    assert _free_end_compliance(nodes) == pytest.approx(expected, rel=EXACT)


def test_serpentine_centreline_follows_table_one():
    d = SpringDesign()
    nodes = serpentine_centreline(d)
    segments = np.hypot(*np.diff(nodes, axis=0).T)
    # turns x (connector + leg) and a last connector: 12 x 4.1 + 2.6 mm of beam.
    assert segments.sum() == pytest.approx(d.turns * (d.pitch_mm + d.length_mm) + d.pitch_mm,
                                           rel=EXACT)
    assert nodes[-1, 0] == pytest.approx((d.turns + 1) * d.pitch_mm, rel=EXACT)


def test_suspension_stiffness_of_table_one():
    s = suspension_stiffness()
    # Table I in acrylic: k_z 60.24 mN/mm, k_phi 18.55 N mm/rad (0.1 %: the printed digits).
    assert s.k_z_n_per_mm * 1e3 == pytest.approx(60.24, rel=1e-3)
    assert s.k_phi_nmm_per_rad == pytest.approx(18.55, rel=1e-3)
    # Linear in E at a fixed Poisson's ratio (both EI and GJ are), to rounding.
    double = suspension_stiffness(SpringDesign(youngs_modulus_n_per_mm2=6400.0))
    assert double.k_z_n_per_mm == pytest.approx(2 * s.k_z_n_per_mm, rel=EXACT)


def test_tilt_stiffness_is_the_same_in_every_direction():
    # Four springs at 90 deg: the 2x2 tilt block is k_phi times the identity, and dz
    # does not couple to tilt (to rounding).
    d = SpringDesign()
    k_local = end_stiffness(serpentine_centreline(d), d.ei_nmm2, d.gj_nmm2)
    total = np.zeros((3, 3))
    for i in range(4):
        beta = math.radians(45.0 + 90.0 * i)
        c, s = math.cos(beta), math.sin(beta)
        x, y = d.hub_radius_mm * c, d.hub_radius_mm * s
        a = np.array([[1.0, y, -x], [0.0, c, s], [0.0, -s, c]])
        total += a.T @ k_local @ a
    scale = total[1, 1]
    assert abs(total[1, 1] - total[2, 2]) / scale < 1e-12
    assert np.abs(total[0, 1:]).max() / scale < 1e-12 and abs(total[1, 2]) / scale < 1e-12


def test_forces_from_signals():
    s = suspension_stiffness()
    assert s.fz_mN(0.5) == pytest.approx(0.5 * s.k_z_n_per_mm * 1e3, rel=EXACT)
    assert s.mb_Nmm(10.0) == pytest.approx(s.k_phi_nmm_per_rad * math.radians(10.0), rel=EXACT)
    assert s.fz_mN(0.0) == 0.0 and math.isnan(s.mb_Nmm(math.nan))


@pytest.mark.parametrize(("key", "value"), [("turns", 0), ("pitch_mm", -1.0),
                                            ("poisson_ratio", 0.5), ("springs", 2),
                                            ("width_mm", math.inf)])
def test_impossible_design_names_the_key(key, value):
    with pytest.raises(SpringDesignError, match=key):
        SpringDesign(**{key: value})
