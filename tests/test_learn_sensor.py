"""The learned estimator on our sensor (issue #24 item 5): the runs cut into tables, the
contact table's r_learned_mm, and the benchmark's scoring.

The preparation step is checked exactly on a hand-made run of 12 frames; the end-to-end
test trains a small model on simulated calibration runs (seed 0, our front end's noise)
and adds its column to the contact table of a held-out run (seed 1).
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from camwhisker.contact.stage import stage_log_from_arrays
from camwhisker.learn.sensor import (
    SENSOR_INPUTS,
    frame_inputs,
    log_r_mm,
    run_tables,
    sensor_columns,
)
from camwhisker.learn.series import LearnError, segments

NAN = np.nan


def test_segments_are_the_runs_of_usable_rows():
    usable = np.array([0, 1, 1, 0, 1, 1, 1, 1, 0, 1], bool)
    assert segments(usable) == [slice(1, 3), slice(4, 8), slice(9, 10)]
    assert segments(usable, 2) == [slice(1, 3), slice(4, 8)]
    assert segments(usable, 5) == []
    assert segments(np.ones(4, bool), 4) == [slice(0, 4)]


def _tiny_run():
    """12 frames: 0-2 before first contact (no dx), 3 theta undefined (phi below the front
    end's floor), 5 untrusted (ok = 0), 10 without a target, 11 out of contact (truth)."""
    n = 12
    ok = np.ones(n, int)
    ok[5] = 0
    phi = np.where(ok > 0, 1.0 + 0.5 * np.arange(n), NAN)
    dz = np.where(ok > 0, 0.01 * np.arange(n), NAN)
    dx = np.where(np.arange(n) >= 3, np.arange(n) - 2.0, NAN)
    theta = np.full(n, 170.0)
    theta[3] = NAN
    contact = {"phi_deg": phi, "dz_mm": dz, "dx_mm": dx, "ok": ok}
    r = 40.0 + 0.1 * np.arange(n)
    r[10] = NAN
    keep = np.arange(n) != 11
    return contact, theta, r, keep


def test_run_tables_cut_every_undefined_frame_and_keep_the_values():
    contact, theta, r, keep = _tiny_run()
    inputs = frame_inputs(contact, theta)
    # theta enters as its cosine and sine (170 deg and -190 deg are the same direction)
    assert inputs["theta_cos"][4] == pytest.approx(np.cos(np.radians(170.0)), abs=1e-15)
    assert np.isnan(inputs["theta_sin"][5])  # untrusted row: theta dropped with phi and dz
    columns = sensor_columns()
    assert columns.inputs == SENSOR_INPUTS and columns.targets == ("r_mm",)
    tables = run_tables(inputs, columns, "tiny", 1, r, keep)
    # usable: frame 4 alone (3: no theta, 5: not ok), then 6-9 (10: no r, 11: no contact)
    assert [t.path for t in tables] == ["tiny[4:5]", "tiny[6:10]"]
    t = tables[1]
    assert t.inputs.shape == (4, 5) and t.targets.shape == (4, 1)
    np.testing.assert_array_equal(t.inputs[:, 0], contact["phi_deg"][6:10])
    np.testing.assert_array_equal(t.inputs[:, 4], [4.0, 5.0, 6.0, 7.0])
    np.testing.assert_array_equal(t.targets[:, 0], r[6:10])
    # a window of 2 frames: the lone frame 4 holds none and is dropped
    assert [t.path for t in run_tables(inputs, columns, "tiny", 2, r, keep)] == ["tiny[6:10]"]
    # without theta, frame 3 joins frame 4
    no_theta = sensor_columns(("phi_deg", "dz_mm", "dx_mm"))
    assert [t.path for t in run_tables(inputs, no_theta, "tiny", 2, r, keep)] == [
        "tiny[3:5]", "tiny[6:10]"]  # fmt: skip
    with pytest.raises(LearnError, match="unknown sensor input.*x_mm"):
        sensor_columns(("phi_deg", "x_mm"))


def test_log_r_at_camera_times():
    log = stage_log_from_arrays(np.array([0.0, 1.0, 2.0]), np.array([0.0, 1.0, 2.0]),
                                np.array([30.0, 32.0, 36.0]), source="cal.stage.csv")
    # camera 5.5 s is stage 0.5 s with an offset of 5 s: halfway from 30 to 32 mm
    r = log_r_mm(log, np.array([4.0, 5.5, 6.5, 7.5]), 5.0)
    np.testing.assert_allclose(r[1:3], [31.0, 34.0], rtol=0, atol=1e-12)
    assert np.isnan(r[0]) and np.isnan(r[3])  # outside the log: no target
    bare = stage_log_from_arrays(np.array([0.0, 1.0]), np.array([0.0, 1.0]), source="run.csv")
    with pytest.raises(LearnError, match="run.csv: no r_mm column"):
        log_r_mm(bare, np.array([0.5]), 0.0)


def test_score_scene_uses_the_same_frames_for_every_estimator():
    from camwhisker.bench.learn_sensor import score_scene

    truth = {"in_contact": np.array([0, 1, 1, 1, 1]), "phi_deg": np.array([0, 1, 3, 4, 5.0]),
             "r_mm": np.array([NAN, 40, 40, 40, 40.0])}  # fmt: skip
    runs = [{"truth": truth}]
    # frame 0 out of contact, 1 below 2 deg, 4 without a GM estimate: frames 2 and 3 scored
    est = {"learned": [np.array([0, 0, 41, 37, 0.0])], "GM": [np.array([0, 0, 40, 40, NAN])]}
    s = score_scene(runs, est)
    assert s["n"] == 2 and s["n_contact"] == 3  # in contact at phi >= 2 deg: 2, 3, 4
    assert s["learned"]["rmse_mm"] == pytest.approx(np.sqrt((1 + 9) / 2), abs=1e-12)
    assert s["learned"]["median_abs_mm"] == pytest.approx(2.0, abs=1e-12)
    assert s["GM"]["rmse_mm"] == 0.0


#: The end-to-end model (3 epochs, phi, dz, dx) on the held-out rigid peg at 50 mm:
#: median |error| ~0.75 mm; 3 mm allows for platforms and torch versions, while a model that
#: learned nothing (the training runs' mean r, ~61 mm) is off by ~6-11 mm on this peg.
E2E_MEDIAN_MAX_MM = 3.0


def test_contact_learned_column_end_to_end(tmp_path, capsys):
    from camwhisker.bench.contact import _log, calibrate_simulated
    from camwhisker.bench.learn_sensor import SensorOptions, prepared_runs, training_tables
    from camwhisker.cli import main
    from camwhisker.contact.calibrate import write_calibration
    from camwhisker.files.tables import read_columns
    from camwhisker.learn.modeldir import save_model
    from camwhisker.learn.train import TrainOptions, train
    from camwhisker.sim.mechanics.experiment import FRONT_END_NOISE, simulate_runs
    from camwhisker.sim.mechanics.files import write_runs

    inputs = ("phi_deg", "dz_mm", "dx_mm")
    opts = SensorOptions(variants=(inputs,))
    calib = calibrate_simulated(0, noise=FRONT_END_NOISE)
    cal_runs = prepared_runs(calib, "rigid", 0, FRONT_END_NOISE, calibration=True)
    training, validation = training_tables(cal_runs, inputs, opts)
    columns = sensor_columns(inputs)
    trained = train(training, validation, columns, opts.window, TrainOptions(epochs=3),
                    progress=False)  # fmt: skip
    model = save_model(tmp_path / "model", trained.net, columns, opts.window, trained.norm,
                       trained.arch, trained.summary)  # fmt: skip
    write_calibration(tmp_path / "calib.toml", calib)
    run = simulate_runs("rigid", 1, noise=FRONT_END_NOISE)[4]  # the peg at 50 mm
    assert run.name == "r50"
    write_runs([run], tmp_path / "runs", 1)
    log = _log(run, False)
    out = tmp_path / "c.csv"
    args = ["contact", "--signals", str(tmp_path / "runs" / "r50_signals.csv"),
            "--stage", str(tmp_path / "runs" / "r50_stage.csv"), "--calib",
            str(tmp_path / "calib.toml"), "--out", str(out)]  # fmt: skip
    assert main(args + ["--learned", str(model)]) == 0
    c = read_columns(out, ("phi_deg", "dz_mm", "dx_mm", "r_learned_mm"))
    assert log.r_mm is None  # the run scored gives no r: nothing but phi, dz and the travel
    defined = np.isfinite(c["r_learned_mm"])
    usable = np.isfinite(c["phi_deg"]) & np.isfinite(c["dz_mm"]) & np.isfinite(c["dx_mm"])
    # every run of usable rows predicts from its window-th row on, nothing elsewhere
    expected = np.zeros_like(usable)
    for seg in segments(usable, opts.window):
        expected[seg.start + opts.window - 1 : seg.stop] = True
    np.testing.assert_array_equal(defined, expected)
    assert defined.sum() > 1000
    tr = run.truth
    sel = defined & (tr["in_contact"] > 0) & (tr["phi_deg"] >= 2.0)
    err = np.abs(c["r_learned_mm"][sel] - tr["r_mm"][sel])
    assert np.median(err) < E2E_MEDIAN_MAX_MM, np.median(err)

    # a model that reads columns a contact table does not offer is named; nothing written
    other = tmp_path / "other"
    shutil.copytree(model, other)
    config = json.loads((other / "config.json").read_text())
    config["inputs"] = ["a", "b", "c"]
    (other / "config.json").write_text(json.dumps(config))
    out.unlink()
    capsys.readouterr()
    assert main(args + ["--learned", str(other)]) == 2
    err_text = capsys.readouterr().err
    assert f"{other}: reads a, b, c -> r_mm" in err_text, err_text
    assert not out.exists()
