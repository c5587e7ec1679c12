"""Contact belief (eq. 1), eta from rest, onsets, and the `belief` command (issue #22 item 3)."""

import json

import numpy as np
import pytest

from camwhisker.cli import main
from camwhisker.contact.belief import (
    ETA_FACTOR,
    ETA_FLOOR_DEG,
    contact_belief,
    contact_flag,
    eta_from_rest,
    eta_source,
    find_onsets,
)
from camwhisker.contact.belief_table import table_belief, write_belief_table
from camwhisker.files.tables import TableError
from camwhisker.sim.mechanics import FRONT_END_NOISE, simulate_runs

# The done-when: the onset within 2 frames of the true one.
ONSET_TOL_FRAMES = 2


def test_eq1_on_hand_made_norms_and_vectors():
    b = contact_belief(np.array([0.0, 0.5, 1.0, 1.5, 2.0, 3.0, np.nan]), eta=1.0)
    assert np.array_equal(b[:6], [0.0, 0.0, 0.0, 0.5, 1.0, 1.0]) and np.isnan(b[6])
    # |(1.5, 2)| = 2.5 = eta: b = 0; |(3, 4)| = 5 = 2 eta: b = 1; |(2.4, 3.2)| = 4: b = 0.6.
    b = contact_belief(np.array([[1.5, 2.0], [3.0, 4.0], [2.4, 3.2]]), eta=2.5)
    assert b == pytest.approx([0.0, 1.0, 0.6], abs=1e-12)  # exact up to rounding
    with pytest.raises(ValueError, match="eta must be positive"):
        contact_belief(np.ones(3), eta=0.0)
    # A live frame's float: the array's value to the bit (the same operations), NaN kept.
    d = np.r_[np.random.default_rng(0).uniform(-3.0, 3.0, 500), np.nan]
    b = [contact_belief(float(v), eta=0.37) for v in d]
    assert np.array_equal(b, contact_belief(d, eta=0.37), equal_nan=True)
    with pytest.raises(ValueError, match="eta must be positive"):
        contact_belief(1.0, eta=np.nan)


def test_eta_is_the_factor_times_the_rest_quantile():
    # 0.1 ... 2.0: the 0.95 quantile interpolates 1.9 and 2.0 at 0.05 -> 1.905.
    d = np.arange(1, 21) / 10.0
    assert eta_from_rest(np.r_[d, np.nan]) == pytest.approx(ETA_FACTOR * 1.905, rel=1e-12)
    # Four frames (a rest of 1.3 s filmed at 3 frames/s) still give their quantile: 0.385.
    few = np.array([0.1, 0.2, np.nan, 0.3, 0.4])
    assert eta_from_rest(few) == pytest.approx(ETA_FACTOR * 0.385, rel=1e-12)
    assert "fewer than 5: give --rest-frames N or --eta-deg X" in eta_source(few, 0.5775)
    # A quiet rest is floored (and says so); no trusted frame at all is an error.
    assert eta_from_rest(np.zeros(10)) == ETA_FLOOR_DEG
    assert eta_source(np.zeros(10), ETA_FLOOR_DEG).startswith("the floor 0.02 deg, above")
    with pytest.raises(ValueError, match="no trusted rest frame"):
        eta_from_rest(np.array([np.nan, np.nan]))


def test_a_whisker_that_settles_off_rest_leaves_contact():
    # A quiet rest (0.002 deg), a contact to 1 deg, then the whisker settles 0.01 deg off
    # rest, as a hand-made build's did: eta from that rest alone (0.005) would hold the
    # contact to the end; the floor ends it where phi falls under it.
    rng = np.random.default_rng(3)
    phi = np.r_[np.abs(rng.normal(0, 0.002, 30)), np.linspace(0.0, 1.0, 40)[1:],
                np.linspace(1.0, 0.01, 20), 0.01 + np.abs(rng.normal(0, 0.002, 40))]
    eta = eta_from_rest(phi[:30])
    assert eta == ETA_FLOOR_DEG
    _, flag, onsets = find_onsets(phi, eta)
    assert len(onsets) == 1 and not flag[-40:].any()
    # It ends on the last frame of the fall above eta (frame 88 of 30 + 39 + 20).
    assert onsets[0].end_frame == 87


def test_flag_has_hysteresis_over_the_band_and_nan_keeps_it():
    b = np.array([0.0, 0.6, 1.0, 0.4, np.nan, 0.0, 0.9, 0.0])
    assert contact_flag(b).astype(int).tolist() == [0, 0, 1, 1, 1, 0, 0, 0]


def test_slow_linear_rise_is_refined_back_to_its_start():
    # Contact from frame 40, |d| rising 0.1 eta per frame: b reaches 1 at frame 60.
    d = np.r_[np.full(40, 0.2), 0.1 * np.arange(1, 41)]
    _, flag, onsets = find_onsets(d, eta=1.0)
    assert len(onsets) == 1 and onsets[0].detected_frame == 59
    assert abs(onsets[0].frame - 40) <= 1  # the line's zero lies within a frame of the truth
    assert flag[:59].sum() == 0 and flag[59:].all()


def test_onsets_of_simulated_stage_runs_within_two_frames():
    # Rigid pegs at the paper's 8 radii, 30 frames/s, the front end's target noise
    # (phi 0.05 deg, isotropic on the tilt vector); eta from the 1 s at rest.
    for run in simulate_runs("rigid", 0, noise=FRONT_END_NOISE):
        phi = np.where(run.signals["ok"] == 1, run.signals["phi_deg"], np.nan)
        true = int(np.flatnonzero(run.truth["in_contact"])[0])
        _, _, onsets = find_onsets(phi, eta_from_rest(phi[:30]))
        assert onsets, run.name
        assert abs(onsets[0].frame - true) <= ONSET_TOL_FRAMES, (run.name, onsets[0], true)


def _write(path, text, sidecar=None):
    path.write_text(text)
    if sidecar is not None:
        path.with_suffix(".json").write_text(json.dumps(sidecar))
    return path


def _table(n_rest=10, jump_at=15, n=20):
    rows = ["frame,t_s,dz_mm,phi_deg,theta_deg,ok,note"]
    for i in range(n):
        phi = 5.0 if i >= jump_at else 0.01 * (1 + i % 3)
        rows.append(f"{i},{i / 30:.6f},0,{phi},,1,")
    return "\n".join(rows) + "\n", {"rest_references": [{"frame": 0, "frames_used": n_rest}]}


def test_table_gets_its_columns_and_the_sidecar_its_onsets(tmp_path):
    text, side = _table()
    src = _write(tmp_path / "s.csv", text, side)
    belief = table_belief(src)
    # Rest |d| 0.01, 0.02, 0.03 repeating: the 0.95 quantile of the 10 is 0.03.
    assert belief.eta_deg == pytest.approx(ETA_FACTOR * 0.03, rel=1e-9)
    out = tmp_path / "b.csv"
    write_belief_table(belief, out)
    header, *rows = out.read_text().splitlines()
    assert header.endswith(",note,contact_b,contact") and len(rows) == 20
    assert rows[14].endswith(",0.0000,0") and rows[15].endswith(",1.0000,1")
    record = json.loads(out.with_suffix(".json").read_text())
    assert record["onsets"] == [{"frame": 15, "detected_frame": 15, "end_frame": 19,
                                 "t_s": pytest.approx(0.5)}]  # fmt: skip
    # Run again on its own output: the columns are replaced, not doubled.
    _write(tmp_path / "b.json", json.dumps(side))
    write_belief_table(table_belief(out), tmp_path / "b2.csv")
    assert (tmp_path / "b2.csv").read_text() == out.read_text()


def test_bad_input_names_the_file_and_the_column(tmp_path, capsys):
    text, side = _table()
    no_phi = _write(tmp_path / "nophi.csv", text.replace("phi_deg", "tilt"), side)
    with pytest.raises(TableError, match="nophi.csv: row 1: missing column phi_deg"):
        table_belief(no_phi)
    bare = _write(tmp_path / "bare.csv", text)
    with pytest.raises(TableError, match="bare.csv: no sidecar .*bare.json"):
        table_belief(bare)
    assert table_belief(bare, rest_frames=10).eta_deg == pytest.approx(0.045)
    few = _write(tmp_path / "few.csv", text, {"rest_references": [{"frame": 0, "frames_used": 3}]})
    assert "over 3 rest frame(s); fewer than 5: give --rest-frames" in table_belief(few).eta_from
    broken = _write(tmp_path / "broken.csv", text.replace(",1,\n", ",0,\n", 10), side)
    with pytest.raises(TableError, match="broken.csv: rest rows 2-11, column phi_deg: no trusted"):
        table_belief(broken)
    empty = _write(tmp_path / "empty.csv", text, {"rest_references": []})
    with pytest.raises(TableError, match="empty.json: key rest_references"):
        table_belief(empty)
    out = tmp_path / "out.csv"
    assert main(["belief", "--signals", str(bare), "--out", str(out)]) == 2
    assert "camwhisker belief: error: " in capsys.readouterr().err and not out.exists()


def test_belief_on_the_rendered_build_clip(tmp_path, build_clip_true):
    # The bundled clip (build 150, held out: measured, not tuned): 1 s at rest, then
    # phi ~24 deg from frame 30 (its truth) to 110, then settling 0.01 deg off rest.
    # conftest: batch on it with its true file, shared with test_build_sample.
    rc, signals = build_clip_true
    assert rc == 0
    out = tmp_path / "clip.belief.csv"
    assert main(["belief", "--signals", str(signals), "--out", str(out)]) == 0
    onsets = json.loads(out.with_suffix(".json").read_text())["onsets"]
    assert len(onsets) == 1 and abs(onsets[0]["frame"] - 30) <= ONSET_TOL_FRAMES
    # The flag lasts the whole deflection and ends with it (eta's floor, not the rest's 0.006).
    assert 110 <= onsets[0]["end_frame"] <= 110 + ONSET_TOL_FRAMES
