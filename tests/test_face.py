"""A contact stuck at an edge, then dragged along a flat face (camwhisker.contact.face).

Tolerances:

- round trip on the model's own travel (200 stuck rows, then 300 dragged along a face at
  70 deg): the stretch ends within 10 rows of the drag's start (each dragged row moves
  the travel 0.05 mm off a stuck contact's, under MAX_RMS_MM until about 7 add up); with
  MF's r exact
  beta within 0.05 deg and each frame's r within 0.01 mm (the bisection's 1e-10 mm and the
  bounded search's tolerance); with MF noisy at 5 mm (about MF's spread in a drag), beta
  within 1 deg and r within 1.5 mm at the 95th percentile (300 rows of 5 mm against r's
  spread of 10 mm pin the drag's scale to about 3 % at one SE, 1 mm at its 35 mm end; 1.5
  SE on this fixed seed, which leaves 0.86 mm);
- a simulated plate tap (the elastica, not the model; taps-bench tuning seed 3, the
  front end's noise): every frame's point with phi >= 2 deg within 2 mm of the truth
  (tuning plates 0-39 leave at most 1.74 mm), where the fusion alone leaves over 3 mm on
  some; the table of the same run along one axis unchanged.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from camwhisker.bench.taps import CALIB_PATH, contact_errors
from camwhisker.contact.calibrate import read_calibration
from camwhisker.contact.face import face_r, fit_face, fit_stuck
from camwhisker.contact.gm import deflection_mm
from camwhisker.contact.space import contact_rows_in_space
from camwhisker.io.poses import pose_log_from_arrays
from camwhisker.sim.mechanics.experiment import FRONT_END_NOISE
from camwhisker.sim.mechanics.taps import protocol_trial, simulate_trial

Y0_MM, X_E_MM, BETA_DEG = 45.0, 3.0, 70.0


@pytest.fixture(scope="module")
def calib():
    return read_calibration(CALIB_PATH)


def _stuck_then_dragged(gm):
    """Travel and phi of a contact stuck at (X_E, Y0) up to phi 8 deg, then dragged along a
    face at BETA_DEG with phi held by friction; the dragged rows' true r."""
    phi_s = np.linspace(1.0, 8.0, 200)
    r_s = np.full_like(phi_s, Y0_MM)
    for _ in range(20):  # stuck at y0 along the shaft: r^2 = y0^2 + G(r)^2
        r_s = np.hypot(Y0_MM, deflection_mm(gm, r_s, phi_s))
    x_s = X_E_MM + deflection_mm(gm, r_s, phi_s)
    r_d = np.linspace(r_s[-1] + 0.1, 80.0, 300)
    phi_d = np.full_like(r_d, 8.0)
    g = deflection_mm(gm, r_d, phi_d)
    x_d = X_E_MM + g + (np.sqrt(r_d ** 2 - g ** 2) - Y0_MM) / math.tan(math.radians(BETA_DEG))
    return np.r_[x_s, x_d], np.r_[phi_s, phi_d], r_d


def test_the_stretch_and_the_face_are_found_from_their_own_travel(calib):
    gm = calib.gm
    x, phi, r_d = _stuck_then_dragged(gm)
    stuck = fit_stuck(gm, x, phi)
    assert 0 <= stuck.last - 199 <= 10
    dragged = slice(200, None)
    fit = fit_face(gm, X_E_MM, Y0_MM, x[dragged], phi[dragged], r_d, np.ones_like(r_d))
    assert fit.taken and abs(fit.beta_deg - BETA_DEG) < 0.05
    r = face_r(gm, X_E_MM, Y0_MM, fit.beta_deg, x[dragged], phi[dragged])
    assert np.max(np.abs(r - r_d)) < 0.01
    noisy = r_d + np.random.default_rng(0).normal(0.0, 5.0, r_d.size)
    fit = fit_face(gm, X_E_MM, Y0_MM, x[dragged], phi[dragged], noisy, np.full_like(r_d, 5.0))
    assert fit.taken and abs(fit.beta_deg - BETA_DEG) < 1.0
    r = face_r(gm, X_E_MM, Y0_MM, fit.beta_deg, x[dragged], phi[dragged])
    assert np.percentile(np.abs(r - r_d), 95) < 1.5


def test_a_contact_that_never_sticks_has_no_stretch(calib):
    phi = np.linspace(1.0, 1.5, 100)  # a pause's worth of phi: no press to fit
    assert fit_stuck(calib.gm, np.linspace(3.0, 4.0, 100), phi) is None


def test_a_plate_tap_is_placed_along_its_face(calib):
    seed = 3  # a plate (seed % 4 == 3)
    runs = simulate_trial(protocol_trial(seed), FRONT_END_NOISE)
    worst, dragged = 0.0, 0
    for tr in runs:
        poses = pose_log_from_arrays(*tr.poses, f"<{tr.name}>")
        cols, _, _ = contact_rows_in_space(tr.signals, poses, calib, None, mode="frame")
        worst = max(worst, float(np.max(contact_errors(cols, tr)["dist"])))
        dragged += int(np.any(tr.run.truth["slipping"]))
    assert dragged >= 2  # the trial has dragged taps to test
    assert worst < 2.0
