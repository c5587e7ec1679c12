"""Calibration files and the contact table: round trip, provenance, degenerate inputs."""

import functools
import math
import tomllib

import numpy as np
import pytest

from camwhisker.contact.calibrate import (
    CalibrationError,
    CalibrationRun,
    calibrate,
    mf_phi_floor,
    mf_table_path,
    read_calibration,
    write_calibration,
)
from camwhisker.contact.fusion import MF_BIAS_FLOOR_MM, mf_bias_floor_mm
from camwhisker.contact.gm import PHI_MIN_DEG
from camwhisker.contact.mf import r_mf
from camwhisker.contact.pipeline import CONTACT_COLUMNS, contact_rows
from camwhisker.contact.stage import stage_log_from_arrays
from camwhisker.contact.zscore import SpreadTable
from camwhisker.sim.mechanics import simulate_runs
from camwhisker.sim.mechanics.experiment import PAPER_RIGID_RADII_MM, NoiseModel, peg_radii


@functools.cache
def calibration():
    runs = simulate_runs("rigid", 31)
    cal_runs = [CalibrationRun(r.signals, stage_log_from_arrays(r.stage["t_s"], r.stage["x_mm"],
                                                                  r.stage["r_mm"]))
                for r in runs]
    return calibrate(cal_runs, 150.0, command="test")[0]


def test_round_trip(tmp_path):
    calib = calibration()
    path = tmp_path / "calib.toml"
    write_calibration(path, calib)
    doc = tomllib.loads(path.read_text())
    assert doc["provenance"]["package"] == "camwhisker"
    assert len(doc["provenance"]["runs"]) == 8
    assert mf_table_path(path).exists()
    back = read_calibration(path)
    assert back.gm.kind == calib.gm.kind
    assert back.gm.params == pytest.approx(calib.gm.params, rel=1e-12)
    assert back.gm.alternatives["eq8"].params["c"] == pytest.approx(
        calib.gm.alternatives["eq8"].params["c"], rel=1e-12)
    assert np.allclose(back.gm_spread.std_mm, calib.gm_spread.std_mm, rtol=1e-12)
    assert np.allclose(back.mf_table.r_mm, calib.mf_table.r_mm, rtol=1e-8)
    assert back.mf_table.phi_min_deg == calib.mf_table.phi_min_deg
    assert np.allclose(back.mf_noise.std_mm, calib.mf_noise.std_mm, rtol=1e-12)
    assert back.mf_bias_floor_mm == pytest.approx(calib.mf_bias_floor_mm, rel=1e-12)
    r, phi = np.array([30.0, 60.0, 200.0]), np.array([5.0, 25.0, 90.0])  # the last off the box
    assert np.allclose(back.bend(r, phi), calib.bend(r, phi), rtol=1e-12)
    assert not list(tmp_path.glob(".*tmp"))  # atomic writes left no temporaries


def test_mf_bias_floor_follows_the_calibrated_radii(tmp_path):
    # The paper's pegs: the fusion's 2 mm, to rounding (each run's radius is r at its first
    # contact, the peg's). 15 pegs evenly in log r: widest gap 0.42 of the paper's.
    assert calibration().mf_bias_floor_mm == pytest.approx(MF_BIAS_FLOOR_MM, rel=1e-9)
    assert mf_bias_floor_mm(peg_radii(15)) == pytest.approx(0.42 * MF_BIAS_FLOOR_MM, rel=0.01)
    # Repeats of a radius (within 1 mm) do not narrow the gaps; two pegs far apart widen them.
    paper = np.array(PAPER_RIGID_RADII_MM)
    assert mf_bias_floor_mm(np.r_[paper, paper + 0.3]) == pytest.approx(MF_BIAS_FLOOR_MM)
    assert mf_bias_floor_mm([30.0, 90.0]) > 4 * MF_BIAS_FLOOR_MM
    with pytest.raises(ValueError, match="two or more radii"):
        mf_bias_floor_mm([40.0, 40.5])
    # A file from before the key reads as the paper's pegs; a bad value is named.
    path = tmp_path / "calib.toml"
    write_calibration(path, calibration())
    text = path.read_text()
    line = next(x for x in text.splitlines() if x.startswith("bias_floor_mm = "))
    path.write_text(text.replace(line + "\n", ""))
    assert read_calibration(path).mf_bias_floor_mm == MF_BIAS_FLOOR_MM
    path.write_text(text.replace(line, "bias_floor_mm = -1.0"))
    with pytest.raises(CalibrationError, match=r"\[mf\] bias_floor_mm must be a positive"):
        read_calibration(path)


def test_mf_phi_floor_from_spread():
    edges = np.array([0.0, 2.5, 5.0, 10.0, 20.0, np.inf])

    def spread(std):
        return SpreadTable(edges, np.full(5, 10), np.zeros(5), np.array(std, float))

    assert mf_phi_floor(spread([25, 20, 9, 3, 1]), 15.0) == 5.0
    assert mf_phi_floor(spread([25, 12, 9, 3, 1]), 15.0) == 2.5
    # Narrow down to phi 0 (a quiet front end): the table's own floor, eq. 8's 1 deg.
    assert mf_phi_floor(spread([14, 12, 9, 3, 1]), 15.0) == PHI_MIN_DEG == 1.0
    assert mf_phi_floor(spread([25, 12, 16, 3, 1]), 15.0) == 10.0  # every bin above it
    assert mf_phi_floor(spread([25, 12, 9, 3, 16]), 15.0) == np.inf  # no MF at all


def test_calibration_mf_floor_and_spreads():
    """The paper's 8 radii at the paper's noise: MF starts where its noise scatter falls
    under 15 mm (2.5 or 5 deg on every seed looked at). The scatter from noise alone is
    below the spread at a left-out radius in every bin above the floor."""
    calib = calibration()
    assert calib.mf_table.phi_min_deg in (2.5, 5.0)
    above = calib.mf_spread.edges_deg[:-1] >= calib.mf_table.phi_min_deg
    assert np.all(calib.mf_noise.std_mm[above] < calib.mf_spread.std_mm[above])
    assert np.all(calib.mf_noise.std_mm[above] <= 15.0)


def test_quiet_front_end_gets_no_mf_estimate_on_an_untouched_whisker(tmp_path):
    # At the noise the front end reaches on hand-made builds (phi 0.02 deg, dz 0.005 mm), on
    # 15 pegs, MF's noise scatter is narrow down to phi 0: the floor must still be the
    # table's own 1 deg, in memory as in the file, or an untouched whisker's noise (phi
    # ~0.03 deg) gets a contact at ~57 mm (as it did, with the floor at 0 in memory).
    runs = simulate_runs("rigid", 31, radii_mm=peg_radii(15),
                         noise=NoiseModel(phi_deg=0.02, dz_mm=0.005))
    calib = calibrate([CalibrationRun(r.signals, stage_log_from_arrays(
        r.stage["t_s"], r.stage["x_mm"], r.stage["r_mm"])) for r in runs], 150.0)[0]
    assert calib.mf_table.phi_min_deg == PHI_MIN_DEG
    path = tmp_path / "calib.toml"
    write_calibration(path, calib)
    assert read_calibration(path).mf_table.phi_min_deg == PHI_MIN_DEG
    assert np.isnan(r_mf(calib.mf_table, [0.03, 0.5], [0.001, 0.002]).r_mm).all()


def test_missing_key_is_named(tmp_path):
    path = tmp_path / "calib.toml"
    write_calibration(path, calibration())
    text = path.read_text().replace("model = ", "modell = ", 1)
    path.write_text(text)
    with pytest.raises(CalibrationError, match=r"\[gm\]: missing key 'model'"):
        read_calibration(path)


def test_bend_correction_fits_the_pegs_and_reads_back_absent_or_named(tmp_path):
    """On the paper's eight pegs at the paper's noise the offset surface takes the GM model's
    error across (a two-parameter beam over 1-35 deg) to under 0.35 of it (seen 0.24 -> 0.06
    mm; what is left is the onset's error in dx), and the shortening takes the spread of a
    peg's height along the whisker to under 0.35 of it (seen 0.06 -> 0.02 mm), neither
    moving a 1-deg point by more than 0.05 mm. A file from before [shape] reads without
    one; a bad table is named."""
    bend = calibration().bend
    print("\nacross {:.3f} -> {:.3f}, along {:.3f} -> {:.3f} mm".format(
        *bend.offset_sd_mm, *bend.shortening_sd_mm))
    for before, after in (bend.offset_sd_mm, bend.shortening_sd_mm):
        assert after < 0.35 * before and before > 0.04
    radii = np.array(PAPER_RIGID_RADII_MM)
    assert np.abs(bend(radii, 1.0)).max() < 0.05
    # No samples (a run without pauses) give no terms, not an error.
    assert [v.shape for v in bend(np.empty(0), np.empty(0))] == [(0,), (0,)]
    path = tmp_path / "calib.toml"
    write_calibration(path, calibration())
    text = path.read_text()
    path.write_text(text[:text.index("[shape]")] + text[text.index("[mf]"):])
    assert read_calibration(path).bend is None
    line = next(x for x in text.splitlines() if x.startswith("phi_powers = "))
    path.write_text(text.replace(line, "phi_powers = [1, 2, 3]"))
    with pytest.raises(CalibrationError, match=r"\[shape\]: offset_coef and shortening_coef"):
        read_calibration(path)


def test_dz_noise_is_the_pause_medians_and_reads_back_absent_or_named(tmp_path):
    """At the paper's 0.04 mm per frame, a median of 36-54 frames scatters 1.25 x 0.04 /
    sqrt(45) = 7.5 um (seen 7.4): within 20 % (the MAD of ~150 pauses, ~9 % relative spread,
    plus the surface's misfit). It reads back; a file from before the key reads without one
    (sigma_MF per phi bin, as then); a bad value is named."""
    calib = calibration()
    assert abs(calib.dz_noise_mm / (1.2533 * 0.04 / math.sqrt(45.0)) - 1.0) < 0.2
    path = tmp_path / "calib.toml"
    write_calibration(path, calib)
    assert read_calibration(path).dz_noise_mm == pytest.approx(calib.dz_noise_mm, rel=1e-9)
    text = path.read_text()
    line = next(x for x in text.splitlines() if x.startswith("dz_noise_mm = "))
    path.write_text(text.replace(line, ""))
    assert read_calibration(path).dz_noise_mm is None
    path.write_text(text.replace(line, "dz_noise_mm = -1.0"))
    with pytest.raises(CalibrationError, match=r"\[mf\] dz_noise_mm must be a positive number"):
        read_calibration(path)


def test_calibration_needs_r():
    run = simulate_runs("rigid", 31)[0]
    log = stage_log_from_arrays(run.stage["t_s"], run.stage["x_mm"], source="L.csv")
    with pytest.raises(CalibrationError, match="L.csv: calibration stage log needs column r_mm"):
        calibrate([CalibrationRun(run.signals, log)], 150.0)


def test_contact_rows_one_per_signal_row_and_empty_while_moving():
    calib = calibration()
    run = simulate_runs("compliant", 32)[0]
    log = stage_log_from_arrays(run.stage["t_s"], run.stage["x_mm"])
    cols, analysis = contact_rows(run.signals, log, calib, mode="pause")
    n = run.signals["t_s"].size
    assert all(cols[c].shape == (n,) for c in CONTACT_COLUMNS)
    moving = np.isnan(cols["pause"])
    assert moving.sum() > 100
    assert np.isnan(cols["r_gm_mm"][moving]).all()
    assert np.isfinite(cols["r_gm_mm"]).sum() > 500
    # Before contact: no dx, no estimates.
    before = cols["x_mm"] < analysis.x_contact_mm - 0.5
    assert before.sum() > 50 and np.isnan(cols["dx_mm"][before]).all()
    assert np.isnan(cols["r_hat_mm"][before]).all()
