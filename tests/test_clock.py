"""Clock offset from continuous motion (camwhisker.contact.clock) and its use by analyse_run."""

import math

import numpy as np
import pytest

from camwhisker.contact.clock import estimate_offset_motion, motion_events, noise_sd
from camwhisker.contact.pipeline import analyse_run
from camwhisker.contact.stage import stage_log_from_arrays
from camwhisker.sim.mechanics.experiment import continuous_protocol, simulate_runs

FRAME_S = 1.0 / 30.0


def _log(run):
    return stage_log_from_arrays(run.stage["t_s"], run.stage["x_mm"])


def _offset_errors_frames(runs):
    errs, ses = [], []
    for run in runs:
        s = run.signals
        e = estimate_offset_motion(_log(run), s["t_s"], [s["phi_deg"], s["dz_mm"]])
        errs.append((e.offset_s - run.offset_s) / FRAME_S)
        ses.append(e.se_s / FRAME_S)
    return np.array(errs), np.array(ses)


def test_noise_sd_of_white_noise():
    # 20,000 samples: the MAD-based sd is within 3 % (about 4 of its standard errors).
    v = np.random.default_rng(1).normal(5.0, 0.2, 20_000)
    assert noise_sd(v) == pytest.approx(0.2, rel=0.03)


def test_events_of_a_continuous_sweep_are_its_start_and_stop():
    run = simulate_runs("rigid", 11, protocol=continuous_protocol(5.0))[0]
    ev = motion_events(_log(run)) + run.offset_s
    # One stage sample (0.05 s) is the resolution of an event in the log.
    np.testing.assert_allclose(ev, run.schedule_t_s[[1, -2]], atol=0.05)


def test_offset_from_continuous_motion_at_5_mm_s():
    """Fast sweeps: the stop pins the offset to about a frame, and the se says how well."""
    errs, ses = _offset_errors_frames(simulate_runs("rigid", 12, protocol=continuous_protocol(5.0)))
    # Median within half a frame, every run within 3 frames (seed 12, 8 radii).
    assert np.median(np.abs(errs)) < 0.5
    assert np.max(np.abs(errs)) < 3.0
    # The standard error is honest: errors within 4 se.
    assert np.all(np.abs(errs) < 4 * ses + 0.25)


def test_offset_from_motion_on_paused_runs():
    errs, _ = _offset_errors_frames(simulate_runs("compliant", 13))
    # Pauses give many stops: within half a frame (measured: <= 0.32 frames on seed 0).
    assert np.max(np.abs(errs)) < 0.5


def test_no_contact_leaves_the_offset_undetermined():
    run = simulate_runs("rigid", 14, protocol=continuous_protocol(5.0))[0]
    s = run.signals
    noise = np.random.default_rng(2).normal(0.3, 0.2, s["t_s"].size)  # phi at rest: no contact
    e = estimate_offset_motion(_log(run), s["t_s"], [noise])
    assert not e and math.isnan(e.offset_s)


def test_analyse_run_without_pauses_and_with_a_given_offset():
    run = simulate_runs("rigid", 15, protocol=continuous_protocol(5.0))[2]
    a = analyse_run(run.signals, _log(run))
    assert not a.paused
    assert abs(a.offset_s - run.offset_s) < 3 * FRAME_S
    # Onset within 0.5 mm: 3 frames of travel at 5 mm/s plus the fit's scatter.
    assert abs(a.x_contact_mm - run.info["x_first_contact_mm"]) < 0.5
    given = analyse_run(run.signals, _log(run), offset_s=run.offset_s + 0.5)
    assert given.offset_s == run.offset_s + 0.5 and not given.offset_estimated


def test_a_box_left_at_the_stop_is_not_read_as_the_offset():
    """The box's whisker slides off its edge as the base stops: contact ends at the stop,
    a kink in phi(x) that a line around the stop reads as an offset (7 frames late before
    the in-contact rule). No event then counts: the spline's offset, se NaN (not pinned)."""
    from camwhisker.contact.stage import CONTACT_PHI_DEG
    from camwhisker.sim.mechanics.experiment import FRONT_END_NOISE

    run = simulate_runs("slide-box", 1, noise=FRONT_END_NOISE,
                        protocol=continuous_protocol(1.0))[0]  # fmt: skip
    s = run.signals
    e = estimate_offset_motion(_log(run), s["t_s"], [s["phi_deg"], s["dz_mm"]],
                               in_contact=s["phi_deg"] >= CONTACT_PHI_DEG)  # fmt: skip
    # Within one frame (measured: 0.16 frames); the stop carries no in-contact window.
    assert abs(e.offset_s - run.offset_s) < FRAME_S
    assert math.isnan(e.se_s)
    a = analyse_run(s, _log(run))
    assert a.offset_s == pytest.approx(e.offset_s, abs=1e-9)
