"""MF, eqs. (9)-(10): hand values and degenerate tables and queries."""

import numpy as np
import pytest

from camwhisker.contact.mf import MF_DOMAIN_RADIUS, MFTable, r_mf


def table():
    phi = np.array([5.0, 10.0, 15.0, 20.0, 5.0, 10.0, 15.0, 20.0])
    dz = np.array([0.05, 0.2, 0.45, 0.8, 0.1, 0.4, 0.9, 1.6])
    r = np.array([30.0, 30.0, 30.0, 30.0, 80.0, 80.0, 80.0, 80.0])
    return MFTable.build(phi, dz, r)


def test_hand_value_two_neighbours():
    t = table()
    # Query between (10, 0.2, r=30) and (10, 0.4, r=80): distances 0.05 and 0.15.
    res = r_mf(t, 10.0, 0.25, k=2)
    expect = (30 / 0.05 + 80 / 0.15) / (1 / 0.05 + 1 / 0.15)
    assert res.r_mm[0] == pytest.approx(expect, rel=1e-12)


def test_exact_match_returns_its_label():
    res = r_mf(table(), [15.0], [0.9])
    assert res.r_mm[0] == 80.0 and not res.outside[0]


def test_duplicate_points_and_exact_match():
    t = MFTable.build([10.0, 10.0, 10.0], [0.3, 0.3, 0.3], [40.0, 60.0, 60.0])
    res = r_mf(t, [10.0, 10.5], [0.3, 0.3])
    assert res.r_mm[0] == pytest.approx(160.0 / 3.0)  # mean of the exact matches
    assert res.r_mm[1] == pytest.approx(160.0 / 3.0)  # equal distances: equal weights


def test_one_row_table():
    t = MFTable.build([10.0], [0.3], [55.0])
    res = r_mf(t, [10.0, 11.0, 30.0], [0.3, 0.3, 0.3])
    assert res.r_mm[:2].tolist() == [55.0, 55.0]
    assert np.isnan(res.r_mm[2]) and res.outside[2]


def test_outside_domain_flagged():
    res = r_mf(table(), [20.0], [1.6 + 2 * MF_DOMAIN_RADIUS])
    assert np.isnan(res.r_mm[0]) and res.outside[0]
    assert res.nearest[0] == pytest.approx(2 * MF_DOMAIN_RADIUS)


def test_nan_and_small_phi_give_nan_not_outside():
    res = r_mf(table(), [np.nan, 10.0, 0.0], [0.2, np.nan, 0.0])
    assert np.isnan(res.r_mm).all()
    assert not res.outside.any()


def test_empty_table_is_an_error():
    with pytest.raises(ValueError, match="at least one row"):
        MFTable.build([np.nan], [0.1], [40.0])


def test_leave_one_out_never_uses_itself():
    t = table()
    res = r_mf(t, t.phi_deg, t.dz_mm, k=1, exclude_self=True)
    # Each point's nearest other point; none of them is an exact match of itself.
    assert np.all(np.isfinite(res.r_mm) | res.outside)
    assert np.all(res.nearest[np.isfinite(res.nearest)] > 0)
