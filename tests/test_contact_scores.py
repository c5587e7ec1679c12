"""Z-dissimilarity (eq. 11), its combined variant, fusion and shapes (eq. 12) on unseen seeds."""

import functools

import numpy as np
import pytest

from camwhisker.bench.contact import (
    calibrate_simulated,
    evaluate_kind,
    evaluate_run,
    pool,
    summary,
)
from camwhisker.contact.fusion import fuse
from camwhisker.contact.shape import reconstruct
from camwhisker.contact.stage import stage_log_from_arrays
from camwhisker.contact.zscore import (
    flag_rates,
    roc_auc,
    spread_table,
    z_combined,
    z_dissimilarity,
)
from camwhisker.sim.mechanics.experiment import (
    NOISE_LEVELS,
    PAPER_RIGID_RADII_MM,
    simulate_run,
)
from camwhisker.sim.mechanics.scenes import PegScene

# Seeds used only here (never looked at while the back end was written; the curve-fitted
# MF table of 2026-11-23 was first tried on them too, its settings then fixed on tuning
# seeds 0/1, 101/102, 201/202 and checked on fresh ones, 7001/7002, 8001/8002, 9001/9002).
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


@pytest.mark.parametrize("level", LEVELS)
def test_compliant_eq11_auc_issue_criterion(level):
    """Issue #4: on compliant contact eq. (11) separates the samples with |GM error| > 15 mm
    at ROC AUC >= 0.9 (0.940 / 0.983 at the paper's / the front end's noise on these seeds;
    0.926-0.998 on tuning seeds 0/1, 101/102, 201/202). Z is defined where MF is, above the
    calibration's MF phi floor; counting the failures below it as not flagged, Z > 1 still
    marks >= 80 % of all failures (61 of 71 at the paper's noise)."""
    ev = evaluation(level, "compliant")
    s = summary(ev)
    assert s["z_score_auc"] >= 0.9
    bad = np.abs(ev["r_true_mm"] - ev["r_gm_mm"]) > 15.0
    flagged = np.nan_to_num(ev["z_score"], nan=0.0) > 1.0
    assert (flagged & bad).sum() >= 0.8 * bad.sum()


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
# The per-sample scores' AUC at that threshold. The bottle's GM error grows smoothly from
# 0 to ~11 mm, and MF scatters by 3-7 mm per pause (its RMSE here), so samples a few mm
# either side of 5 mm cannot be ranked one by one: on the tuning seeds (0/1, 101/102,
# 201/202, both noise levels) eq. (11) reached 0.76-0.90 and the combined score
# 0.73-0.92. The fusion's P(GM failed), which averages MF over pauses, reached >= 0.98.
BOTTLE_Z_AUC_FLOOR = 0.7


@pytest.mark.parametrize("level", LEVELS)
def test_scores_flag_bottle_slide(level):
    """Bottle swept from both sides (the whisker's side slides down it, r falls while GM
    keeps reporting about the first contact): the samples where GM is off by > 5 mm are
    separated by both Z scores (AUC >= BOTTLE_Z_AUC_FLOOR) and by the fusion's P(GM failed)
    (AUC >= 0.9); eq. (11) flags >= 80 % of them at Z > 1, the combined score (a wider
    spread, so a higher bar) flags fewer good samples than eq. (11)."""
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
        assert auc >= BOTTLE_Z_AUC_FLOOR
    assert roc_auc(np.where(defined, 1.0 - ev["p_gm_good"], np.nan), bad) >= 0.9
    assert rates["z_score"][0] >= 0.8
    assert rates["z_combined"][1] <= rates["z_score"][1]
    # Both sides: the -x sweep is reconstructed on the bottle's right (eq. 12's sign).
    right = ev["run"] == 1
    assert np.nanmin(ev["x_hat_mm"][right]) > 0.0 > np.nanmax(ev["x_hat_mm"][~right])


@pytest.mark.parametrize("kind", SCENES)
@pytest.mark.parametrize("level", LEVELS)
def test_fused_not_worse_than_better_method(level, kind):
    s = summary(evaluation(level, kind))
    best = min(s["gm_rmse_mm"], s["mf_rmse_mm"])
    print(f"\n{level} {kind}: GM {s['gm_rmse_mm']:.2f}  MF {s['mf_rmse_mm']:.2f}  "
          f"fused {s['fused_rmse_mm']:.2f} mm")
    assert s["fused_rmse_mm"] <= best


@pytest.mark.parametrize("level", LEVELS)
def test_rigid_contact_between_calibrated_radii(level):
    """Rigid pegs halfway (geometric mean) between the calibration's radii, where MF
    interpolates between calibrated curves: MF's mean error over each contact is under half
    the gap between the two calibrated radii (the most a look-up that answers with the
    nearer curve can be off; 4-5 mm at the widest gap, 72.5-90 mm, on these seeds), and the
    fused estimate is GM's (no GM failure to correct)."""
    radii = np.sqrt(np.array(PAPER_RIGID_RADII_MM[:-1]) * np.array(PAPER_RIGID_RADII_MM[1:]))
    rng = np.random.default_rng(EVAL_SEED)
    noise = NOISE_LEVELS[level]
    parts = []
    for i, r in enumerate(radii):
        run = simulate_run(f"u{r:.1f}", "rigid", PegScene(float(r)), rng, noise=noise)
        log = stage_log_from_arrays(run.stage["t_s"], run.stage["x_mm"])
        parts.append(evaluate_run(calibration(level), run.signals, log, run.truth, run.scene,
                                  run.offset_s, i))
    ev = pool(parts)
    mf_err = ev["r_true_mm"] - ev["r_mf_mm"]
    per_run = np.array([np.nanmean(mf_err[ev["run"] == i]) for i in range(radii.size)])
    print(f"\n{level}: per-contact mean MF error " + " ".join(f"{v:.1f}" for v in per_run))
    assert np.all(np.abs(per_run) < 0.5 * np.diff(PAPER_RIGID_RADII_MM))
    s = summary(ev)
    assert s["fused_rmse_mm"] <= s["gm_rmse_mm"] < 1.0


def test_eq12_hand_value():
    x_hat, y_hat = reconstruct([10.0, 10.0], [60.0, 60.0], [30.0, 30.0], [0.5, 0.5],
                               [1.0, -1.0])
    assert x_hat.tolist() == pytest.approx([-20.0, 40.0])  # 10 -/+ 60 sin 30 deg
    assert y_hat[0] == pytest.approx(60.0 * np.cos(np.radians(30.0)) - 0.5)


def test_eq12_on_the_bent_whisker_places_the_true_contact():
    """With true r and phi, eq. 12 on the whisker bent as the calibration has it (the GM
    model read backwards, the bend correction) and less the plate's dz puts the simulator's
    contact (rigid 76 and 30 mm pegs, phi 1-30 deg) within 0.05 mm across the whisker (seen
    0.04) and 0.06 mm along it (seen 0.04); the GM model alone lags across by 0.5 mm past
    20 deg, and eq. 12 as printed (straight) by up to 1 mm at 20."""
    calib = calibration("front-end")
    across, along = {"bent": [], "gm": [], "straight": []}, []
    for peg, seed in ((76.0, 4), (30.0, 6)):
        tr = simulate_run(f"u{peg:g}", "rigid", PegScene(peg), np.random.default_rng(seed),
                          noise=NOISE_LEVELS["front-end"]).truth
        sel = (tr["in_contact"] > 0) & (tr["phi_deg"] > 1.0)
        args = (tr["x_mm"][sel], tr["r_mm"][sel], tr["phi_deg"][sel], tr["dz_mm"][sel], 1.0)
        for name, gm, bend in (("bent", calib.gm, calib.bend), ("gm", calib.gm, None),
                               ("straight", None, None)):
            x_hat, y_hat = reconstruct(*args, gm=gm, bend=bend)
            across[name].append(np.abs(x_hat - tr["contact_x_mm"][sel]))
            if name == "bent":
                along.append(np.c_[tr["phi_deg"][sel], np.abs(y_hat - tr["contact_y_mm"][sel])])
    across = {k: np.concatenate(v) for k, v in across.items()}
    phi, err = np.concatenate(along).T
    print(f"\nacross: bent {across['bent'].max():.3f}, GM alone {across['gm'].max():.2f}, "
          f"straight {across['straight'].max():.2f} mm; along {err.max():.3f} mm (phi up to "
          f"{phi.max():.1f} deg)")
    assert phi.max() > 29.0 and across["bent"].max() < 0.05
    assert across["gm"].max() > 0.4 and across["straight"].max() > 0.5
    assert err.max() < 0.06


@pytest.mark.parametrize("level", LEVELS)
def test_box_shape_within_3mm(level):
    """Box: reconstructed points (eq. 12 with the fused r) with eq.-(11) Z < 0.5 (signed, as
    in the paper) in the rigid, non-slipping stretch lie within 3 mm of the true outline; so
    do those with the combined-spread Z < 0.5. (Of the 10 stuck pauses, Z is defined on
    the 7 above MF's phi floor.)"""
    ev = evaluation(level, "slide-box")
    stuck = np.isfinite(ev["profile_dist_mm"]) & ~ev["slipping"]
    for z, min_points in (("z_score", 4), ("z_combined", 4)):
        sel = stuck & (ev[z] < 0.5)
        assert sel.sum() >= min_points
        assert np.max(ev["profile_dist_mm"][sel]) < 3.0


@pytest.mark.parametrize("level", LEVELS)
def test_bottle_shape_within_3mm(level):
    """Bottle: a smooth convex profile has no stuck stretch (the point of tangency slides from
    the first touch), so every low-Z point is held to the profile, slipping or not. They lie
    within 3 mm, and so does every point: an error in r moves a point along the whisker's
    base direction, nearly tangent to the bottle there. Few points have Z < 0.5: GM's
    error exceeds 2 mm from phi ~7 deg on, and MF (so Z) starts at its phi floor."""
    ev = evaluation(level, "slide-circle")
    dist = ev["profile_dist_mm"]
    defined = np.isfinite(dist)
    for z, min_points in (("z_score", 2), ("z_combined", 5)):
        sel = defined & (ev[z] < 0.5)
        assert sel.sum() >= min_points
        assert np.max(dist[sel]) < 3.0
    assert defined.sum() >= 40 and np.max(dist[defined]) < 3.0


def test_z_of_one_row_is_its_batch_value():
    rng = np.random.default_rng(0)
    r_gm = np.r_[rng.normal(50.0, 10.0, 300), np.nan, 1.0, 2.0, np.inf]
    r_mf = np.r_[rng.normal(50.0, 10.0, 300), 1.0, np.nan, 2.0, 3.0]
    sigma = np.r_[rng.uniform(-0.2, 3.0, 300), 1.0, 1.0, 0.0, 1.0]  # some <= 0: no Z
    z, zc = z_dissimilarity(r_gm, r_mf, sigma), z_combined(r_gm, r_mf, sigma, sigma[::-1])
    for i in range(r_gm.size):
        one = slice(i, i + 1)
        # The live row's floats do the batch's operations: equal to the last bit.
        assert np.array_equal(z_dissimilarity(r_gm[one], r_mf[one], sigma[one]), z[one],
                              equal_nan=True)
        assert np.array_equal(z_combined(r_gm[one], r_mf[one], sigma[one], sigma[::-1][one]),
                              zc[one], equal_nan=True)
    assert np.isfinite(z).sum() > 200 and np.isnan(z).sum() > 10  # both kinds met
