"""Slip from GM's own estimates, and the fusion's line through a slip's growing GM bias."""

import numpy as np
import pytest
from scipy.signal import lfilter

from camwhisker.contact.fusion import MEMORY_SAMPLES, OnlineFusion, _two_sided, fuse
from camwhisker.contact.pipeline import doubt
from camwhisker.contact.slip import (
    STUCK_RATE,
    OnlineSlip,
    slip_segments,
    slip_state,
    slipped,
    slipping,
)


def _stick_then_slide(rng, n_stick=10, n_slide=25, rate=2.5, sigma=0.3):
    """Pauses 1 mm apart: a stuck contact at 40 mm drifting out 0.4 mm per mm, then a slide
    whose r_GM runs away at ``rate`` mm per mm; r_GM with ``sigma`` of noise."""
    dx = np.arange(1.0, n_stick + n_slide + 1.0)
    r = 40.0 + 0.4 * np.minimum(dx, n_stick) + rate * np.maximum(dx - n_stick, 0.0)
    return dx, r + sigma * rng.standard_normal(dx.size), np.full(dx.size, sigma)


def test_a_stuck_contact_rarely_slips_and_a_slide_stays_found():
    # 200 noise draws at GM's largest spread (1 mm at the paper's noise, phi < 2.5 deg) and
    # at the front end's (0.3 mm); r_GM runs away at 2.7 mm per mm, the slowest on the
    # tuning sweeps. A stuck pause enters slip when the noise of a difference (sqrt(2)
    # sigma) passes the allowance less the drift, 3.4 of it: 3e-4 of the 1,800 comparisons,
    # 0.6 expected at sigma 1 (2 allowed), none at sigma 0.3. At sigma 0.3 the slide is
    # found within its first three pauses (169, 29 and 2 of 200) and then held: leaving
    # it needs a rise under 1 mm, 4 of the difference's sigmas below 2.7.
    rng = np.random.default_rng(3)
    for sigma, most in ((1.0, 2), (0.3, 0)):
        false = 0
        for _ in range(200):
            dx, r, sg = _stick_then_slide(rng, rate=2.7, sigma=sigma)
            state = slip_state(slipping(r, dx, sg))
            false += int(state[:10].sum())
            if sigma == 0.3:
                assert state[12:].min() == 1.0
        assert false <= most


def test_slip_needs_a_rise_over_the_stuck_drift_and_its_noise():
    dx = np.arange(1.0, 11.0)
    sg = np.full(dx.size, 0.01)
    assert np.nanmax(slipping(40.0 + 0.9 * STUCK_RATE * dx, dx, sg)) == 0.0
    assert np.nanmin(slipping(40.0 + 1.1 * STUCK_RATE * dx, dx, sg)) == 1.0
    # Over the drift but within 3 sigma of it: undecided.
    assert np.isnan(slipping(40.0 + 1.02 * STUCK_RATE * dx, dx, sg)[1:]).all()


def test_a_move_between_pauses_does_not_make_a_stuck_contact_slip():
    # Frame by frame on a paused stage (rigid peg, front end's noise): the local line
    # behind each frame's r_GM straddles each start and stop, so the last frames of a pause
    # dip to 37 mm and the moving ones swing up to 47 mm about a stuck 43 mm. Compared
    # frame to frame, each pause rose by 6 mm from the dip a step back: 73 % of these
    # frames were held as sliding (13 % of the rigid pegs' frames on the contact bench's
    # paused runs). Compared by the median per bin of travel, none is.
    r, dx = [], []
    for step in range(1, 8):
        r += [43.0] * 26 + [41.0, 39.0, 37.0]
        dx += [float(step)] * 29
        r += [38.0, 41.0, 44.0, 47.0]
        dx += [step + 0.1, step + 0.4, step + 0.7, step + 0.95]
    state = slip_state(slipping(np.array(r), np.array(dx), np.full(len(r), 0.3)))
    assert state.max() == 0.0


def test_slip_state_keeps_through_gaps_and_restarts_at_each_contact():
    s = np.array([np.nan, 0.0, 1.0, np.nan, 1.0, np.nan, 0.0, 1.0])
    seg = np.array([0, 0, 0, 0, 0, 1, 1, 1])
    assert slip_state(s, seg).tolist() == [0, 0, 1, 1, 1, 0, 0, 1]
    assert slip_segments(slip_state(s, seg), seg).tolist() == [0, 0, 1, 1, 1, 2, 2, 3]
    # Once slid, slipped for the rest of its contact, stuck again or not.
    assert slipped([0, 0, 1, 0, 0, 0, 0, 1], seg).tolist() == [0, 0, 1, 1, 1, 0, 0, 1]
    assert slipped(np.zeros(0)).size == 0


def test_no_samples_no_segments():
    # A run without pauses has no pause samples: no segment ids either (one id for none
    # made the fusion's sums index past the empty data).
    assert slip_segments(np.zeros(0)).size == 0
    r, p, m = fuse([], [], [], [], 150.0, slip_segments(np.zeros(0)), trend=np.zeros(0, bool))
    assert r.size == p.size == m.size == 0


def test_two_sided_sums_match_each_segment_filtered_alone():
    rng = np.random.default_rng(1)
    v = rng.exponential(size=60) * np.repeat([1e-3, 1e3, 1.0, 10.0], 15)
    seg = np.repeat([0, 1, 2, 3], 15)
    lam = 1.0 - 1.0 / MEMORY_SAMPLES
    want = np.concatenate([
        lfilter([1.0], [1.0, -lam], x) + lfilter([1.0], [1.0, -lam], x[::-1])[::-1] - x
        for x in np.split(v, 4)])
    # A segment after one 1e6 times larger keeps its own sums to 1e-9 relative.
    assert np.allclose(_two_sided(v, seg, MEMORY_SAMPLES), want, rtol=1e-9, atol=0)


def test_a_slide_is_fused_from_a_line_through_the_growing_bias():
    # GM's bias grows 3 mm a pause along a slide; MF scatters 2 mm about the truth. Over
    # 200 noise draws, a mean of the bias over +-5 pauses is 9-11 mm off at the slide's two
    # ends (the slope times the memory); the line's mean error there is under 0.5 mm (seen
    # 0.18) and its scatter under 1.5 mm (seen 1.1: a line's end is its least certain point).
    rng = np.random.default_rng(5)
    k = np.arange(20.0)
    truth = 50.0 + 2.2 * k
    r_gm = truth + 3.0 * k
    ones = np.ones(k.size)
    line, mean = [], []
    for _ in range(200):
        r_mf = truth + 2.0 * rng.standard_normal(k.size)
        line.append(fuse(r_gm, r_mf, 0.3 * ones, 2.0 * ones, 150.0, trend=ones > 0)[0] - truth)
        mean.append(fuse(r_gm, r_mf, 0.3 * ones, 2.0 * ones, 150.0)[0] - truth)
    ends = np.r_[0, 1, 18, 19]
    line, mean = np.array(line)[:, ends], np.array(mean)[:, ends]
    assert np.abs(line.mean(axis=0)).max() < 0.5 and line.std(axis=0).max() < 1.5
    assert np.abs(mean.mean(axis=0)).min() > 5.0


@pytest.mark.parametrize(("slip", "want"), [(None, "onset"), ([1], "onset;slip"),
                                            ([0], "onset"), ([np.nan], "onset")])
def test_doubt_names_every_reason(slip, want):
    assert doubt([0.0], [0.5], 1 / 30, slip)[0] == want
    assert doubt([10.0], [5.0], 1 / 30, slip)[0] == want.replace("onset", "fast")


def test_live_slip_and_fusion_are_batch_at_the_newest_sample():
    # Pauses (one sample per bin of travel): OnlineSlip gives slip_state(slipping()) sample
    # by sample, and OnlineFusion, told the state, gives fuse() with slip's segments and
    # line at the newest sample (float rounding only: 1e-12 relative).
    rng = np.random.default_rng(8)
    dx, r_gm, sg = _stick_then_slide(rng, rate=4.0)
    want = slip_state(slipping(r_gm, dx, sg))
    live = OnlineSlip()
    got, slid = [], []
    for r, x, s in zip(r_gm, dx, sg, strict=True):
        got.append(live(r, x, s))
        slid.append(live.slipped)
    assert np.array_equal(got, want)
    assert np.array_equal(slid, slipped(want))
    r_mf = 40.0 + 2.2 * np.maximum(dx - 10.0, 0.0) + 2.0 * rng.standard_normal(dx.size)
    s_mf = np.full(dx.size, 2.0)
    seg = slip_segments(want)
    fusion = OnlineFusion()
    for i in range(dx.size):
        one = fusion(r_gm[i:i + 1], r_mf[i:i + 1], sg[i:i + 1], s_mf[i:i + 1], 150.0,
                     bool(want[i]))
        whole = fuse(r_gm[:i + 1], r_mf[:i + 1], sg[:i + 1], s_mf[:i + 1], 150.0,
                     segment=seg[:i + 1], trend=want[:i + 1] > 0)
        for g, w in zip(one, whole, strict=True):
            np.testing.assert_allclose(g[0], w[-1], rtol=1e-12, atol=1e-9, equal_nan=True)
