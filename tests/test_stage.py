"""Stage logs: validation, pauses, clock offset, pause medians."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from camwhisker.contact.stage import (
    PAUSE_TRIM_S,
    StageLogError,
    _offset_scores,
    best_offset,
    contact_onset_x,
    detect_pauses,
    estimate_offset,
    pause_index,
    pause_medians,
    read_stage_log,
    stage_log_from_arrays,
)
from camwhisker.sim.mechanics import simulate_runs


def _write(tmp_path, text):
    p = tmp_path / "stage.csv"
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    ("body", "needle"),
    [
        ("0,0\n0.1,0\n0.05,0\n", "row 4: time goes backwards (unsorted): t_s = 0.05 after 0.1"),
        ("0,0\n0.1,0\n0.1,0\n", "row 4: duplicate time: t_s = 0.1 after 0.1"),
        ("0,0\n0.1,abc\n", "row 3, column x_mm: not a number: 'abc'"),
        ("0,0\n5.0,0\n", "row 3: gap of 5.000 s after t_s = 0.0 "),
        ("0,0\n0.1,nan\n", "row 3, column x_mm: not a finite number"),
    ],
)
def test_bad_logs_name_file_row_problem(tmp_path, body, needle):
    p = _write(tmp_path, "t_s,x_mm\n" + body)
    with pytest.raises(StageLogError) as err:
        read_stage_log(p)
    assert str(p) in str(err.value)
    assert needle in str(err.value)
    assert "np." not in str(err.value)  # issue #21 item 9: numbers plain, not numpy reprs


def test_missing_column(tmp_path):
    p = _write(tmp_path, "t,x_mm\n0,0\n")
    with pytest.raises(StageLogError, match=r"row 1: missing column t_s \(header: t, x_mm\)"):
        read_stage_log(p)


def test_read_with_r(tmp_path):
    p = _write(tmp_path, "t_s,x_mm,r_mm\n0,0,50\n0.5,0,50\n1.0,1,50\n")
    log = read_stage_log(p)
    assert log.r_mm.tolist() == [50.0, 50.0, 50.0]
    assert log.x_at([0.75, 2.0])[0] == pytest.approx(0.5)
    assert np.isnan(log.x_at([2.0])[0])


def test_pauses_are_found():
    # Rest 2 s, move 0.25 s, pause 1.2 s, move, pause 0.8 s (too short), move, rest 2 s.
    t = np.arange(0, 8.0, 0.05)
    knots_t = [0, 2, 2.25, 3.45, 3.7, 4.5, 4.75, 8.0]
    knots_x = [0, 0, 1, 1, 2, 2, 3, 3]
    log = stage_log_from_arrays(t, np.interp(t, knots_t, knots_x))
    p = detect_pauses(log)
    assert p.x_mm.tolist() == [0.0, 1.0, 3.0]
    assert p.t_end_s[1] - p.t_start_s[1] == pytest.approx(1.2, abs=0.05 + 1e-9)


def test_offset_estimated_to_a_frame():
    """Offsets of several seconds come back to within 0.05 s (1.5 frames at 30 fps),
    well inside PAUSE_TRIM_S (0.1 s), so pause medians never mix two steps."""
    errs = []
    for run in simulate_runs("rigid", 2718)[::3] + simulate_runs("compliant", 2718):
        log = stage_log_from_arrays(run.stage["t_s"], run.stage["x_mm"])
        s = run.signals
        off, score = estimate_offset(log, s["t_s"], s["phi_deg"], s["dz_mm"])
        errs.append(off - run.offset_s)
        assert score > 0.9
    assert np.max(np.abs(errs)) < 0.05


def _explained_one(signal, idx, pauses, x):
    """The explained share at one offset, frame by frame as the docstring of
    estimate_offset states it (pause means, np.interp between them, frames off the log
    counted with their full deviation)."""
    sel = (idx >= 0) & np.isfinite(signal)
    finite = np.isfinite(signal)
    use = np.isfinite(x) & finite
    if sel.sum() < 6 or use.sum() < 6:
        return 0.0
    levels = {p: signal[sel & (idx == p)].mean() for p in np.unique(idx[sel])}
    xp = np.array([pauses.x_mm[p] for p in levels])
    order = np.argsort(xp, kind="stable")
    model = np.interp(x[use], xp[order], np.array(list(levels.values()))[order])
    mean = signal[finite].mean()
    total = np.sum((signal[finite] - mean) ** 2)
    unexplained = np.sum((signal[use] - model) ** 2) + np.sum((signal[finite & ~use] - mean) ** 2)
    return 1.0 - unexplained / total


def test_offset_scores_match_a_per_offset_evaluation():
    """The offset search scores all trial offsets at once: each score must be the one
    offset's, frame by frame, up to float rounding, and the estimate the same."""
    run = simulate_runs("compliant", 5)[1]
    log = stage_log_from_arrays(run.stage["t_s"], run.stage["x_mm"])
    pauses = detect_pauses(log)
    assert np.ptp(pauses.t_end_s - pauses.t_start_s) > 0.3  # unequal pauses (jitter 1.2-1.8 s)
    s = run.signals
    t = s["t_s"].copy()
    t[[400, 900]] = np.nan  # frames without a time: in no pause, off the log
    phi = np.where(s["ok"], s["phi_deg"], np.nan)
    phi[100:130] = np.nan  # a tracking gap inside the run
    signals = [phi, s["dz_mm"]]
    offsets = np.r_[np.arange(-30.0, 30.05, 0.1), run.offset_s + np.arange(-0.2, 0.2, 0.004)]

    def reference(trial):
        return np.array([np.mean([_explained_one(v, pause_index(t, pauses, o, PAUSE_TRIM_S),
                                                 pauses, log.x_at(t - o)) for v in signals])
                         for o in trial])  # fmt: skip

    ref = reference(offsets)
    order = np.argsort(t)  # as estimate_offset orders the frames: by time, NaN last
    got = _offset_scores(log, pauses, t[order], [v[order] for v in signals], offsets)
    # Sums in another order: the scores (O(1)) differ by rounding, ~1e-16.
    assert np.max(np.abs(got - ref)) <= 1e-12
    assert ref.max() > 0.9  # the true offset explains the signals
    off, score = estimate_offset(log, t, phi, s["dz_mm"])
    assert (off, score) == pytest.approx(best_offset(reference, (-30.0, 30.0)), abs=1e-12)
    assert abs(off - run.offset_s) < 0.05  # within 1.5 frames, as above
    # Frames in any order give the same estimate (sorted first), up to rounding.
    perm = np.random.default_rng(0).permutation(t.size)
    assert estimate_offset(log, t[perm], phi[perm], s["dz_mm"][perm]) == pytest.approx(
        (off, score), abs=1e-12)


def test_pause_medians_and_onset():
    run = simulate_runs("rigid", 161)[4]
    log = stage_log_from_arrays(run.stage["t_s"], run.stage["x_mm"], run.stage["r_mm"])
    s = run.signals
    pt = pause_medians(log, s["t_s"], s["phi_deg"], s["dz_mm"], s["ok"], run.offset_s)
    truth_phi = np.interp(pt.x_mm, run.steps.base_x_mm, np.nan_to_num(run.steps.phi_deg))
    # Median of ~30 frames of 0.22 deg noise: error < 0.2 deg (5 sigma of the median).
    # At rest phi is the magnitude of a noisy tilt, biased by ~1.25 sigma: left out.
    sel = truth_phi > 2.0
    assert sel.sum() > 20
    assert np.max(np.abs(pt.phi_deg[sel] - truth_phi[sel])) < 0.2
    x0 = contact_onset_x(pt.x_mm, pt.phi_deg)
    assert abs(x0 - run.info["x_first_contact_mm"]) < 0.2  # a fifth of a step


def test_onset_without_contact_is_nan():
    assert np.isnan(contact_onset_x([0, 1, 2], [0.1, 0.2, 0.1]))
    assert np.isnan(contact_onset_x([0, 1, 2], [np.nan, np.nan, np.nan]))


def test_onset_from_the_rise_when_contact_slips_under_5_deg():
    """A contact that slips at 4.9 deg: phi rises 1.1 deg per mm from x0 = 0.1 mm, then
    stays level (and sinks a little) until contact is lost. The onset line must end where
    phi levels off: through the level it would reach back past the log's first pause."""
    rng = np.random.default_rng(3)
    x = np.arange(-3.0, 23.0)
    phi = np.clip(1.1 * (x - 0.1), 0.0, 4.9) - 0.015 * np.clip(x - 4.0, 0.0, None)
    phi[-1] = 0.0  # contact lost
    phi = phi + 0.01 * rng.standard_normal(x.size) + 0.06  # pause medians' noise, rest bias
    # The rise's 4 pauses alone give x0 within a tenth of a step (their noise: ~0.02 mm).
    assert abs(contact_onset_x(x, phi) - 0.1) < 0.1
    # Travelling the other way: the same contact mirrored.
    assert abs(contact_onset_x(-x, phi, travel_sign=-1.0) + 0.1) < 0.1


def test_onset_of_a_plain_rise_uses_every_small_pause():
    """No level: the split is not taken and x0 is the line through all pauses under 5 deg."""
    rng = np.random.default_rng(4)
    x = np.arange(-2.0, 12.0)
    phi = np.clip(0.4 * (x - 0.3), 0.0, None) + 0.01 * rng.standard_normal(x.size)
    use = (phi >= 1.0) & (phi < 5.0)
    slope, intercept = np.polyfit(x[use], phi[use], 1)
    assert contact_onset_x(x, phi) == pytest.approx(-intercept / slope, abs=1e-9)


@pytest.mark.parametrize("x_true, slope, level", [(0.1, 0.96, 2.4), (0.124, 2.08, 3.3)])
def test_onset_when_contact_slips_within_two_pauses(x_true, slope, level):
    """Slip after one or two contact pauses (phi under CONTACT_PHI_DEG at the first in the
    first case): the onset comes from the first contact pause and the pause before it.
    Error bound: 0.2 mm, a fifth of a step (a line through the level: 0.9-1.9 mm off)."""
    x = np.arange(-3.0, 17.0)
    phi = np.minimum(slope * np.clip(x - x_true, 0.0, None), level) - 0.01 * np.clip(x - 3, 0, None)
    phi[-1] = 0.0
    phi = phi + 0.06 + 0.01 * np.random.default_rng(5).standard_normal(x.size)
    assert abs(contact_onset_x(x, phi) - x_true) < 0.2


def test_onset_from_the_frames_of_a_slow_sweep():
    """Frames of continuous sweeps at 1 mm/s (the front end's noise): single frames near
    the onset dip under CONTACT_PHI_DEG and must not end the onset's fit. Seen: within
    0.03 mm on every run; bound 0.2 mm, a fifth of the simulator's 1 mm step."""
    from camwhisker.sim.mechanics.experiment import FRONT_END_NOISE, continuous_protocol

    for run in simulate_runs("rigid", 1, noise=FRONT_END_NOISE, protocol=continuous_protocol(1.0)):
        log = stage_log_from_arrays(run.stage["t_s"], run.stage["x_mm"])
        x = log.x_at(run.signals["t_s"] - run.offset_s)
        x0 = contact_onset_x(x, run.signals["phi_deg"], log.travel_sign)
        assert abs(x0 - run.info["x_first_contact_mm"]) < 0.2, run.name


@settings(max_examples=200, deadline=None)
@given(phi=st.lists(st.one_of(st.floats(-1.0, 40.0), st.just(float("nan"))), min_size=1,
                    max_size=40),
       step=st.sampled_from([0.0, 0.1, 1.0]), sign=st.sampled_from([1.0, -1.0]))
def test_onset_is_nan_or_between_the_first_sample_and_the_first_contact(phi, step, sign):
    """Any phi (levels, NaNs, repeated positions, a travel that does not move): the onset
    is NaN without contact, else a finite x between the first sample and the first contact."""
    phi = np.array(phi)
    x = sign * step * np.arange(phi.size)
    x0 = contact_onset_x(x, phi, sign)
    ok = np.isfinite(phi)
    hit = np.flatnonzero(phi[ok] >= 1.0)
    if hit.size == 0:
        assert np.isnan(x0)
    else:
        u0, first = sign * x0, sign * x[ok][hit[0]]
        assert np.isfinite(x0) and sign * x[ok][0] - 1e-9 <= u0 <= first + 1e-9
