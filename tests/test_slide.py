"""A contact sliding along a smooth object (camwhisker.contact.slide).

Tolerances:

- round trip on the model's own travel: r0 within 0.05 mm and a within 0.005 mm/deg, the
  solver's tolerance on 200 exact rows;
- simulated taps (the elastica, not the model; tuning seeds of taps-bench, front end's
  noise on phi): a sphere's slide taken and its r within 1.0 mm of the truth (median over
  frames with phi >= 2 deg; the model leaves 0.02-0.64 mm on noise-free taps of seeds 0-7,
  the noise adds about 0.3 mm), and eq. 8's GM off by over 3 mm on the same frames (the
  contact slid); a plate's stuck tap not taken.
"""

from __future__ import annotations

import numpy as np
import pytest

from camwhisker.bench.taps import CALIB_PATH
from camwhisker.contact.calibrate import read_calibration
from camwhisker.contact.gm import r_gm
from camwhisker.contact.slide import MIN_ROWS, _travel, fit_slide
from camwhisker.sim.mechanics.experiment import FRONT_END_NOISE
from camwhisker.sim.mechanics.taps import protocol_trial, simulate_tap


@pytest.fixture(scope="module")
def gm():
    return read_calibration(CALIB_PATH).gm


def _tap(seed: int):
    """The first sensor's tap of a taps-bench trial (seed % 4: R100, R150, R300, plate)."""
    trial = protocol_trial(seed)
    tr = simulate_tap(trial.taps[0], np.random.default_rng([seed, 3]), "tap", FRONT_END_NOISE)
    t = tr.run.truth
    contact = t["in_contact"].astype(bool)
    phi = np.asarray(tr.run.signals["phi_deg"], float)
    return t, contact, phi


def test_the_fit_finds_the_slide_it_was_made_from(gm):
    phi = np.linspace(1.0, 15.0, 200)
    x = _travel(gm, 2.0, 80.0, -1.5, phi)
    fit = fit_slide(gm, x, phi)
    assert fit.taken
    assert abs(fit.r0_mm - 80.0) < 0.05 and abs(fit.a_mm_per_deg + 1.5) < 0.005
    assert fit.rms_mm < 1e-3


def test_a_contact_at_one_r_is_not_a_slide(gm):
    phi = np.linspace(1.0, 15.0, 200)
    fit = fit_slide(gm, _travel(gm, 2.0, 60.0, 0.0, phi), phi)
    assert not fit.taken and abs(fit.r0_mm - 60.0) < 0.05


def test_too_little_contact_gives_no_fit(gm):
    phi = np.linspace(1.0, 15.0, MIN_ROWS - 1)
    assert fit_slide(gm, _travel(gm, 2.0, 60.0, -1.0, phi), phi) is None
    phi = np.linspace(1.0, 2.5, 100)  # a pause's worth of phi, not a press
    assert fit_slide(gm, _travel(gm, 2.0, 60.0, -1.0, phi), phi) is None


@pytest.mark.parametrize("seed", [0, 2])
def test_a_sphere_tap_slides_and_its_r_follows(gm, seed):
    t, contact, phi = _tap(seed)
    fit = fit_slide(gm, t["x_mm"][contact], phi[contact])
    assert fit.taken and fit.a_mm_per_deg < 0.0
    use = contact & (t["phi_deg"] >= 2.0) & np.isfinite(phi)
    err = np.abs(fit.r_mm(phi[use]) - t["r_mm"][use])
    assert np.median(err) < 1.0
    assert np.nanmedian(np.abs(r_gm(gm, t["dx_mm"][use], phi[use]) - t["r_mm"][use])) > 3.0


def test_a_plate_tap_is_not_a_slide(gm):
    t, contact, phi = _tap(3)
    fit = fit_slide(gm, t["x_mm"][contact], phi[contact])
    assert fit is not None and not fit.taken
