"""The Python API (``import camwhisker as cw``): the same numbers as the commands."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import camwhisker as cw
from camwhisker.cli import main
from camwhisker.contact.stage import StageLogError
from camwhisker.files.tables import TableError

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_frames"
CAL_RUNS = ("r22.5", "r42.5", "r60", "r90")


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """simulate-stage's calibration runs and a compliant run, and the commands' outputs."""
    root = tmp_path_factory.mktemp("api")
    assert main(["dev", "simulate-stage", "--kind", "eq8", "--out", f"{root}/cal",
                 "--seed", "21"]) == 0
    assert main(["dev", "simulate-stage", "--kind", "compliant", "--out", f"{root}/comp",
                 "--seed", "22"]) == 0
    args = ["calibrate", "--out", f"{root}/calib.toml"]
    for r in CAL_RUNS:
        args += ["--signals", f"{root}/cal/{r}_signals.csv", "--stage", f"{root}/cal/{r}_stage.csv"]
    assert main(args) == 0
    assert main(["contact", "--signals", f"{root}/comp/c35_signals.csv", "--stage",
                 f"{root}/comp/c35_stage.csv", "--calib", f"{root}/calib.toml",
                 "--out", f"{root}/c35.csv"]) == 0
    return root


def test_track_returns_batchs_table(tmp_path):
    sensor = SAMPLES / "nominal.sensor.toml"
    assert main(["batch", str(SAMPLES / "nominal.mp4"), "--sensor", str(sensor),
                 "--out", str(tmp_path / "n.csv"), "--quiet"]) == 0
    df = cw.track(SAMPLES / "nominal.mp4", sensor=sensor)
    # Exactly equal: every cell, dtype and column of the table batch writes.
    pd.testing.assert_frame_equal(df, pd.read_csv(tmp_path / "n.csv"))
    assert df.shape == (90, 12) and int(df["ok"].sum()) == 90


def test_importing_the_package_loads_neither_pandas_nor_the_front_end():
    code = "import sys, camwhisker; print(sorted({'pandas', 'cv2'} & set(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_readers_check_what_they_read(sim, tmp_path):
    signals = cw.read_signals(f"{sim}/comp/c35_signals.csv")
    assert list(signals.columns[:6]) == ["frame", "t_s", "dz_mm", "phi_deg", "theta_deg", "ok"]
    stage = cw.read_stage_log(f"{sim}/comp/c35_stage.csv")
    assert list(stage.columns[:2]) == ["t_s", "x_mm"] and len(stage) > 10
    bad = tmp_path / "bad.stage.csv"
    bad.write_text("t_s,x_mm\n0,0\n1,1\n0.5,2\n")
    with pytest.raises(StageLogError, match=r"bad.stage.csv: row 4: time goes backwards"):
        cw.read_stage_log(bad)
    with pytest.raises(TableError, match="no_such.csv"):
        cw.read_signals(tmp_path / "no_such.csv")


def test_calibrate_and_contact_from_dataframes_match_the_commands(sim):
    runs = [(cw.read_signals(f"{sim}/cal/{r}_signals.csv"),
             cw.read_stage_log(f"{sim}/cal/{r}_stage.csv")) for r in CAL_RUNS]
    calib = cw.calibrate(runs)
    written = cw.read_calibration(f"{sim}/calib.toml")
    # The file holds the fit to its printed digits; the fit itself is the same.
    assert calib.gm.kind == written.gm.kind
    for k, v in written.gm.params.items():
        assert calib.gm.params[k] == pytest.approx(v, rel=1e-5), k
    got = cw.contacts(cw.read_signals(f"{sim}/comp/c35_signals.csv"),
                     cw.read_stage_log(f"{sim}/comp/c35_stage.csv"), calib)
    want = cw.read_contacts(f"{sim}/c35.csv")
    assert len(got) == len(want)
    for col in ("x_mm", "phi_deg", "r_gm_mm", "r_mf_mm", "r_hat_mm"):
        a, b = got[col].to_numpy(float), want[col].to_numpy(float)
        assert np.array_equal(np.isnan(a), np.isnan(b)), col
        # The table prints 4-6 significant digits; 1e-3 mm is below its last digit.
        assert np.nanmax(np.abs(a - b)) < 1e-3, col


def test_percept_from_a_contact_dataframe(sim):
    from_path = cw.perceive([f"{sim}/c35.csv"])
    from_frame = cw.perceive([cw.read_contacts(f"{sim}/c35.csv")])
    assert from_frame.best.model == from_path.best.model
    for k, v in from_path.best.params.items():
        assert from_frame.best.params[k] == pytest.approx(v, abs=1e-9)  # the same numbers read


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="give one pose per contact table"):
        cw.perceive([pd.DataFrame({"t_s": [0.0]})], poses=[])
    with pytest.raises(ValueError, match="<run 0>: no column frame"):
        cw.calibrate([(pd.DataFrame({"t_s": [0.0]}), pd.DataFrame({"t_s": [0.0]}))])


def test_a_pose_log_reads_as_a_dataframe_or_a_named_error(tmp_path):
    from camwhisker.io.poses import PoseLogError

    good = ROOT / "sample_frames" / "space" / "h+0run0.pose.csv"
    df = cw.read_pose_log(good)
    assert list(df.columns) == ["t_s", "x_mm", "y_mm", "z_mm", "qw", "qx", "qy", "qz"]
    norm = (df[["qw", "qx", "qy", "qz"]] ** 2).sum(axis=1) ** 0.5
    assert float((norm - 1).abs().max()) < 1e-6  # written to 9 digits
    bad = tmp_path / "b.pose.csv"
    bad.write_text("t_s,x_mm,y_mm,z_mm,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n1,0,0,0,2,0,0,0\n")
    with pytest.raises(PoseLogError, match="b.pose.csv: row 3, columns qw-qz"):
        cw.read_pose_log(bad)


def test_contacts_and_perceive_in_space_from_dataframes():
    # The bundled sweep in space: a pose log as the base gives the points in W, and the
    # tables as DataFrames give the same cylinder as the percept command (README: 48.25 mm).
    space = ROOT / "sample_frames" / "space"
    tables = [cw.contacts(cw.read_signals(space / f"{n}.signals.csv"),
                          cw.read_pose_log(space / f"{n}.pose.csv"), space / "calib.toml",
                          per="pause")
              for n in ("h-30run0", "h-30run1", "h+0run0", "h+0run1", "h+30run0", "h+30run1")]
    assert all({"px_mm", "py_mm", "pz_mm", "nx", "ny", "nz"} <= set(t.columns) for t in tables)
    p = cw.perceive(tables)
    assert p.best.model == "cylinder"
    # The command reads the tables as printed (6 digits); in memory they are exact.
    assert abs(p.best.params["radius_mm"] - 48.25) < 0.05
    with pytest.raises(ValueError, match="mount goes with a pose log"):
        cw.contacts(cw.read_signals(space / "h+0run0.signals.csv"),
                    ROOT / "sample_frames" / "experiment" / "bottle_left.stage.csv",
                    space / "calib.toml", mount="0,0,0,1,0,0,0")
