"""Z-dissimilarity (eq. 11), its combined variant, fusion and shapes (eq. 12) on unseen seeds."""

import functools

import numpy as np
import pytest

from camwhisker.contact.bench import calibrate_simulated, evaluate_kind, summary
from camwhisker.contact.fusion import fuse
from camwhisker.contact.shape import reconstruct
from camwhisker.contact.zscore import (
    flag_rates,
    roc_auc,
    spread_table,
    z_combined,
    z_dissimilarity,
)
from camwhisker.mechanics.experiment import NOISE_LEVELS

# Seeds used only here (never looked at while the back end was written).
CALIB_SEED, EVAL_SEED = 5150, 6021
PAPER_FALSE_FLAG = 0.26  # Sec. III-D: Z > 1 for 26 % of the good samples
# Both noise levels of issue #4 ("the paper's levels or lower, as chosen"): the paper's
# measured RMSE (phi 0.22 deg, dz 0.04 mm) and our front end's targets (0.05 deg, 0.02 mm).
LEVELS = list(NOISE_LEVELS)
SCENES = ["rigid", "compliant", "slide-box", "slide-circle"]


@functools.cache
def calibration(level):
    return calibrate_simulated(CALIB_SEED, noise=NOISE_LEVELS[level])


@functools.cache
def extended_calibration(level):
    return calibrate_simulated(CALIB_SEED, "rigid-extended", noise=NOISE_LEVELS[level])


@functools.cache
def evaluation(level, kind):
    return evaluate_kind(calibration(level), kind, EVAL_SEED, noise=NOISE_LEVELS[level])


def _scores(s):
    names = (("eq.11", "z_score"), ("combined", "z_combined"), ("P(GM failed)", "p_bad"))
    return " | ".join(f"{name} AUC {s[k + '_auc']:.3f} hit {s[k + '_hit']:.2f} "
                      f"ff {s[k + '_false']:.2f}" for name, k in names)


def test_z_hand_values():
    assert float(z_dissimilarity(60.0, 50.0, 2.0)) == 5.0  # Eq. (11)
    assert float(z_combined(60.0, 50.0, 3.0, 4.0)) == 2.0  # 10 / 5
    z = z_dissimilarity([60.0, np.nan, 60.0, 60.0], [50.0, 50.0, np.nan, 50.0], [2.0, 2.0, 2.0, 0])
    assert z[0] == 5.0 and np.isnan(z[1:]).all()


def test_auc_and_rates_hand_values():
    s = np.array([0.1, 0.4, 0.35, 0.8, np.nan])
    pos = np.array([False, False, True, True, True])
    assert roc_auc(s, pos) == pytest.approx(0.75)
    assert roc_auc([1.0, 1.0], [True, False]) == pytest.approx(0.5)  # ties count half
    assert np.isnan(roc_auc([1.0, 2.0], [True, True]))
    assert flag_rates(s, pos, 0.3) == (1.0, 0.5)


def test_spread_table_bins_and_lookup():
    phi = np.array([1.0, 1.5, 2.0, 2.2, 2.4, 7.0, 7.0, 7.0, 7.0, 7.0, 7.0])
    err = np.array([1.0, -1.0, 1.0, -1.0, 0.0, 2.0, -2.0, 2.0, -2.0, 0.0, 0.0])
    t = spread_table(phi, err)
    assert t.std_mm[0] == pytest.approx(np.std(err[:5], ddof=1))
    assert t.sigma_at([7.0])[0] == pytest.approx(np.std(err[5:], ddof=1))
    assert t.sigma_at([30.0])[0] == pytest.approx(np.std(err, ddof=1))  # empty bin: pooled
    assert np.isnan(t.sigma_at([np.nan])[0])


def test_fuse_degenerate_inputs():
    r, p, m = fuse([50.0, np.nan, 50.0], [np.nan, 40.0, 52.0], [1.0, 1.0, 1.0],
                   [10.0, 10.0, 10.0], 150.0, segment=[0, 1, 2])
    assert r[0] == 50.0 and r[1] == 40.0
    assert np.isnan(p[:2]).all()
    assert np.isfinite(r[2]) and 0.0 < p[2] <= 1.0 and m[2] == pytest.approx(-2.0)


@pytest.mark.parametrize("level", LEVELS)
def test_compliant_gm_biased_and_eq11_flags_it(level):
    """Compliant contact (pipe cleaner radii 35, 55, 90 mm): GM overestimates r (Table III:
    mean r - r_GM = -23.5 mm); eq. (11) Z > 1 for >= 80 % of |GM error| > 15 mm."""
    s = summary(evaluation(level, "compliant"))
    print(f"\n{level} compliant: n={s['n']} bad={s['n_bad']} | {_scores(s)} "
          f"| paper ff {PAPER_FALSE_FLAG:.2f}")
    assert s["gm_mean_mm"] < -15.0
    assert abs(s["mf_mean_mm"]) < 5.0  # MF stays accurate (Table III: |mu_MF| < 7.4 mm)
    assert s["n_bad"] > 30
    assert s["z_score_hit"] >= 0.8


# What eq. (11) reaches on compliant contact alone (seeds above): AUC 0.77 at the paper's
# noise, 0.69 at the front end's. Mechanism, measured per run (paper noise): within
# compliant contact every GM estimate is biased (r - r_GM = -31, -19, -10 mm at the
# 35, 55, 90 mm pegs), so "bad" vs "good" is the 55 mm run against the 90 mm run. The
# 90 mm run sits at the edge of the MF table (the largest calibration radius is 90 mm),
# where the k = 7 neighbour mean is pulled inward: MF underestimates r there by ~10 mm.
# So r_GM - r_MF is ~20 mm for both runs and no per-sample score built on it can rank
# them (the plain difference reaches AUC 0.66-0.69); eq. (11)'s division by
# sigma_GM(phi) only reorders samples by phi. Lower noise does not change either effect.
# Calibrating on the "rigid-extended" runs instead (one more peg a step of the paper's
# spacing beyond each end, 18.5 and 109.7 mm: CALIBRATION_EXTRA_RADII_MM) removes most of
# that edge bias (tuning seeds 101/102, 201/202, 301/302: mean MF error of the 90 mm
# rigid run +7.4 -> +3.6 mm) and lifts the AUC here to 0.821 / 0.797 (test below), still
# short of 0.9: what is left is pauses with phi < 5 deg, where dz is too small to tell
# radii apart and MF is the table's local mean (tuning seeds: AUC over phi >= 5 deg alone
# 0.93-0.98). It is not the default because it lowers the bottle's score AUC (eq. (11)
# 0.858 here at the front end's noise, below test_scores_flag_bottle_slide's 0.9; see
# the constant's comment). These floors guard against regressions; they are not the
# issue's 0.9.
EQ11_COMPLIANT_AUC_FLOOR = {"paper": 0.72, "front-end": 0.62}


@pytest.mark.parametrize("level", LEVELS)
def test_compliant_eq11_auc_reached(level):
    s = summary(evaluation(level, "compliant"))
    assert s["z_score_auc"] >= EQ11_COMPLIANT_AUC_FLOOR[level]


@pytest.mark.parametrize("level", LEVELS)
def test_extended_calibration_lifts_compliant_eq11_auc(level):
    """Pegs beyond the paper's outermost radii in the calibration take MF's edge bias off the
    90 mm compliant run: eq. (11) separates compliant failures better (0.821 / 0.797 on these
    seeds against 0.77 / 0.69), short of the issue's 0.9 (see the comment above)."""
    calib = extended_calibration(level)
    s = summary(evaluate_kind(calib, "compliant", EVAL_SEED, noise=NOISE_LEVELS[level]))
    base = summary(evaluation(level, "compliant"))
    print(f"\n{level} compliant eq. (11) AUC: paper radii {base['z_score_auc']:.3f}, "
          f"extended {s['z_score_auc']:.3f}")
    # A clear gain, not noise: the smallest gain on the 6 tuning cases (seeds 101-302, both
    # noise levels) was 0.075, on these seeds it is ~0.05 (paper) and ~0.11 (front end).
    assert s["z_score_auc"] >= base["z_score_auc"] + 0.04


@pytest.mark.xfail(strict=True, reason="issue #4 asks eq. (11) AUC >= 0.9 on compliant contact "
                   "alone; it reaches 0.77 (paper noise) and 0.69 (front-end noise): see "
                   "EQ11_COMPLIANT_AUC_FLOOR")
@pytest.mark.parametrize("level", LEVELS)
def test_compliant_eq11_auc_issue_criterion(level):
    assert summary(evaluation(level, "compliant"))["z_score_auc"] >= 0.9


@pytest.mark.parametrize("level", LEVELS)
def test_fusion_evidence_separates_compliant_failures(level):
    """Within compliant contact alone the fusion's run-level posterior P(GM failed)
    separates the failures (AUC >= 0.9) where eq. (11) cannot."""
    s = summary(evaluation(level, "compliant"))
    assert s["p_bad_auc"] >= 0.9
    assert s["p_bad_hit"] >= 0.8


@pytest.mark.parametrize("level", LEVELS)
def test_scores_flag_box_slip(level):
    """Slipping box (Coulomb slip up its face, phi steady): GM overestimates r by > 15 mm
    and every score separates those samples (AUC >= 0.9, >= 80 % flagged at Z > 1)."""
    ev = evaluation(level, "slide-box")
    s = summary(ev)
    print(f"\n{level} slide-box: n={s['n']} bad={s['n_bad']} | {_scores(s)} "
          f"| paper ff {PAPER_FALSE_FLAG:.2f}")
    assert s["n_bad"] >= 10
    bad = np.abs(ev["r_true_mm"] - ev["r_gm_mm"]) > 15.0
    assert ev["slipping"][bad].all()  # the failures are the slip
    for key in ("z_score", "z_combined", "p_bad"):
        assert s[f"{key}_auc"] >= 0.9
        assert s[f"{key}_hit"] >= 0.8


# The bottle's GM failure is smaller than the box's (it grows to ~11 mm, never the paper's
# 15 mm): samples count as failed beyond 5 mm, above the GM error of every rigid
# calibration radius (sigma_GM <= 3 mm in Table II and in our calibrations).
BOTTLE_BAD_GM_ERROR_MM = 5.0


@pytest.mark.parametrize("level", LEVELS)
def test_scores_flag_bottle_slide(level):
    """Bottle swept from both sides (the whisker's side slides down it, r falls while GM
    keeps reporting about the first contact): both Z scores separate the samples where GM
    is off by > 5 mm (AUC >= 0.9); eq. (11) flags >= 80 % of them at Z > 1, the combined
    score (a wider spread, so a higher bar) flags fewer good samples than eq. (11)."""
    ev = evaluation(level, "slide-circle")
    err = ev["r_true_mm"] - ev["r_gm_mm"]
    defined = np.isfinite(err) & np.isfinite(ev["r_mf_mm"])
    bad = np.abs(err) > BOTTLE_BAD_GM_ERROR_MM
    assert (bad & defined).sum() >= 20 and (~bad & defined).sum() >= 10
    assert ev["slipping"][bad].all()  # the failures are the slide
    rates = {}
    for key in ("z_score", "z_combined"):
        score = np.where(defined, ev[key], np.nan)
        auc = roc_auc(score, bad)
        rates[key] = flag_rates(score, bad, 1.0)
        print(f"\n{level} bottle {key}: AUC {auc:.3f} hit {rates[key][0]:.2f} "
              f"ff {rates[key][1]:.2f}")
        assert auc >= 0.9
    assert rates["z_score"][0] >= 0.8
    assert rates["z_combined"][1] <= rates["z_score"][1]
    # Both sides: the -x sweep is reconstructed on the bottle's right (eq. 12's sign).
    right = ev["run"] == 1
    assert np.nanmin(ev["x_hat_mm"][right]) > 0.0 > np.nanmax(ev["x_hat_mm"][~right])


# The fusion keeps GM while GM - MF stays within a few sigma of MF's per-contact error (its
# 3 mm floor): on the bottle that difference runs from -4 to +10 mm, so the fused estimate
# stays GM (RMSE 6.6-6.8 mm) where MF alone does better (3.9-6.1 mm; tuning seeds 101-302,
# prior, floor and memory varied: no setting fixes the bottle without costing elsewhere).
# Also tried (tuning seeds, then these seeds): the "rigid-extended" calibration, with
# which the RMS of the bias estimate m on rigid contacts falls from 3.28 to 1.99 mm, a 2 mm
# floor, and the correction m max(0, 1 - se^2/m^2) (empirical Bayes) for (1 - p) m. The
# bottle passed (tuning: fused 3.61 mm mean against MF 5.75, all 24 scene cases <= the
# better method; here fused 3.36 / 3.20 against MF 5.88 / 4.42 mm), but the box's stuck
# points moved ~8 mm (test_box_shape_within_3mm: 8.70 / 8.78 mm here) and the extended
# calibration costs the bottle's score AUC (see EQ11_COMPLIANT_AUC_FLOOR's comment).
# Clipping that correction to lie between MF and GM kept the box's shape on the tuning
# seeds (not run on these) but not the bottle's AUC, so the fusion is unchanged.
FUSION_FAILS = pytest.mark.xfail(strict=True, reason="issue #4: fused RMSE <= the better of GM "
                                 "and MF is not met on the bottle slide (fused = GM > MF)")


@pytest.mark.parametrize("kind", [*SCENES[:3], pytest.param(SCENES[3], marks=FUSION_FAILS)])
@pytest.mark.parametrize("level", LEVELS)
def test_fused_not_worse_than_better_method(level, kind):
    s = summary(evaluation(level, kind))
    best = min(s["gm_rmse_mm"], s["mf_rmse_mm"])
    print(f"\n{level} {kind}: GM {s['gm_rmse_mm']:.2f}  MF {s['mf_rmse_mm']:.2f}  "
          f"fused {s['fused_rmse_mm']:.2f} mm")
    assert s["fused_rmse_mm"] <= best


def test_eq12_hand_value():
    x_hat, y_hat = reconstruct([10.0, 10.0], [60.0, 60.0], [30.0, 30.0], [1.0, -1.0])
    assert x_hat.tolist() == pytest.approx([-20.0, 40.0])  # 10 -/+ 60 sin 30 deg
    assert y_hat[0] == pytest.approx(60.0 * np.cos(np.radians(30.0)))


@pytest.mark.parametrize("level", LEVELS)
def test_box_shape_within_3mm(level):
    """Box: reconstructed points (eq. 12 with the fused r) with eq.-(11) Z < 0.5 (signed, as
    in the paper) in the rigid, non-slipping stretch lie within 3 mm of the true outline; so
    do those with the combined-spread Z < 0.5, which passes more of them."""
    ev = evaluation(level, "slide-box")
    stuck = np.isfinite(ev["profile_dist_mm"]) & ~ev["slipping"]
    for z, min_points in (("z_score", 3), ("z_combined", 8)):
        sel = stuck & (ev[z] < 0.5)
        assert sel.sum() >= min_points
        assert np.max(ev["profile_dist_mm"][sel]) < 3.0


@pytest.mark.parametrize("level", LEVELS)
def test_bottle_shape_within_3mm(level):
    """Bottle: a smooth convex profile has no stuck stretch (the point of tangency slides from
    the first touch), so every low-Z point is held to the profile, slipping or not. They lie
    within 3 mm, and so does every point: an error in r moves a point along the whisker's
    base direction, nearly tangent to the bottle there."""
    ev = evaluation(level, "slide-circle")
    dist = ev["profile_dist_mm"]
    defined = np.isfinite(dist)
    for z, min_points in (("z_score", 5), ("z_combined", 8)):
        sel = defined & (ev[z] < 0.5)
        assert sel.sum() >= min_points
        assert np.max(dist[sel]) < 3.0
    assert defined.sum() >= 40 and np.max(dist[defined]) < 3.0
