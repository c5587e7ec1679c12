"""Rigs of several sensors on one carrier: the rig file, the folder's layout, and
``camwhisker experiment`` on a simulated rig at signal level.

The rig experiment's videos are stand-ins (empty files): each sensor's signal tables are
the simulator's, written with complete sidecars where ``batch`` puts them, so the
experiment reuses them as it does a finished batch (resumable) and runs calibrate,
contact, percept and map as for filmed runs. Filmed rigs: ``camwhisker dev
space-filmed-bench --rig`` (too slow for a test).
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camwhisker.cli import main
from camwhisker.files.tables import write_csv
from camwhisker.io.poses import read_pose_log
from camwhisker.io.rig import RigError, dump_rig, read_rig
from camwhisker.run.campaign import write_sidecar
from camwhisker.run.experiment import run_experiment
from camwhisker.sensor.file import Sensor, dump_sensor
from camwhisker.sim.mechanics import simulate_runs
from camwhisker.sim.mechanics.space import (
    HEIGHTS_MM,
    RIG_SENSORS,
    carrier_poses,
    pose_columns,
    rig_mounts,
    simulate_space_sweep,
    truth_in_world,
)

SPACE = Path(__file__).resolve().parents[1] / "sample_frames" / "space"
#: The rig sweep's seed: the bundled sample's cylinder (its planar runs give 0.02 mm, README).
SEED = 1
_SIGNALS = ("frame", "t_s", "dz_mm", "phi_deg", "theta_deg", "ok")
_CENTRE = ("center_x_mm", "center_y_mm", "center_z_mm")
_AXIS = ("axis_x", "axis_y", "axis_z")


# --- the rig file -----------------------------------------------------------------------


def test_a_rig_file_gives_each_sensors_mount_files_and_order(tmp_path):
    (tmp_path / "a.sensor.toml").write_text(dump_sensor(Sensor()))
    shutil.copy(SPACE / "calib.toml", tmp_path / "b.calib.toml")
    (tmp_path / "rig.toml").write_text(
        '[[sensor]]\nname = "a"\nmount = [1, 2.5, -3, 2, 0, 0, 0.0009]\n'
        'sensor_file = "a.sensor.toml"\n\n'
        '[[sensor]]\nname = "b-2"\nposition_mm = [0, 0, 10]\nquat = [0, 0, 0, 1]\n'
        'calibration = "b.calib.toml"\n')  # fmt: skip
    with pytest.raises(RigError, match=r"sensor a, key mount: the quaternion's norm is 2"):
        read_rig(tmp_path / "rig.toml")
    text = (tmp_path / "rig.toml").read_text().replace("2, 0, 0, 0.0009", "1, 0, 0, 0.0009")
    (tmp_path / "rig.toml").write_text(text)
    rig = read_rig(tmp_path / "rig.toml")
    assert rig.names == ["a", "b-2"]
    a, b = rig.sensors
    # A norm of 1.0000004 (within 1e-3) is rounding: kept, and the quaternion made unit.
    assert np.allclose(a.mount.position_mm, [1.0, 2.5, -3.0], atol=0)
    assert abs(np.linalg.norm(a.mount.quat) - 1.0) < 1e-12
    assert np.allclose(b.mount.quat, [0, 0, 0, 1]) and b.mount.position_mm[2] == 10.0
    assert a.sensor_file == tmp_path / "a.sensor.toml" and a.calibration is None
    assert b.calibration == tmp_path / "b.calib.toml" and b.sensor_file is None
    # dump_rig writes what read_rig reads back, to the last bit of each number.
    (tmp_path / "back.toml").write_text(dump_rig(
        [("x", (0.1, -30.0, 1e-9, 0.6, 0.8, 0.0, 0.0), None, None)], "a\ncomment"))
    x = read_rig(tmp_path / "back.toml").sensors[0]
    assert x.mount.position_mm.tolist() == [0.1, -30.0, 1e-9]
    assert x.mount.quat.tolist() == [0.6, 0.8, 0.0, 0.0]


_GOOD = '[[sensor]]\nname = "a"\nmount = [0, 0, 0, 1, 0, 0, 0]\n'


@pytest.mark.parametrize("body, message", [
    ('[[sensor]]\nname = "a"\n', r"rig.toml: sensor a: key mount missing"),
    ('[[sensor]]\nname = "a"\nmount = [0, 0, 0, 1.01, 0, 0, 0]\n',
     r"sensor a, key mount: the quaternion's norm is 1.01, not 1"),
    ('[[sensor]]\nname = "a"\nposition_mm = [0, 0, 0]\nquat = [0.5, 0, 0, 0]\n',
     r"sensor a, key quat: the quaternion's norm is 0.5"),
    ('[[sensor]]\nname = "a"\nposition_mm = [0, 0, 0]\n', r"sensor a: key quat missing"),
    ('[[sensor]]\nname = "a"\nmount = [0, 0, 1, 0, 0, 0]\n',
     r"sensor a, key mount: expected a list of 7 finite numbers"),
    ('[[sensor]]\nname = "a"\nmount = [0, 0, 0, 1, 0, 0, 0]\nquat = [1, 0, 0, 0]\n',
     r"sensor a: give the mount once"),
    (_GOOD + _GOOD, r"rig.toml: sensor a, key name: given twice"),
    (_GOOD + "mass_g = 3\n", r"sensor a: unknown key mass_g"),
    (_GOOD + 'calibration = "none.toml"\n', r"sensor a, key calibration: no such file"),
    ('[[sensor]]\nname = "../a"\nmount = [0, 0, 0, 1, 0, 0, 0]\n',
     r"\[\[sensor\]\] 1, key name: expected the name of its recordings' folder"),
    ("carrier = 1\n", r"rig.toml: unknown key carrier"),
    ("", r"rig.toml: no sensor"),
    ("[[sensor]\n", r"rig.toml: not valid TOML"),
])  # fmt: skip
def test_a_bad_rig_file_is_named_by_file_sensor_and_key(tmp_path, body, message):
    (tmp_path / "rig.toml").write_text(body)
    with pytest.raises(RigError, match=message):
        read_rig(tmp_path / "rig.toml")


# --- the folder's layout ----------------------------------------------------------------


def _layout(root: Path, files: list[str], rig: str) -> Path:
    root.mkdir()
    (root / "rig.toml").write_text(rig)
    (root / "sensor.toml").write_text(dump_sensor(Sensor()))
    for f in files:
        (root / f).parent.mkdir(parents=True, exist_ok=True)
        (root / f).write_text("t_s,x_mm,r_mm\n" if f.endswith(".stage.csv") else "")
    return root


_TWO = _GOOD + '\n[[sensor]]\nname = "b"\nmount = [0, 30, 0, 1, 0, 0, 0]\n'
_CAL = ["a/calibration_r1.mp4", "a/calibration_r1.stage.csv", "b/calibration_r1.mp4",
        "b/calibration_r1.stage.csv"]  # fmt: skip


@pytest.mark.parametrize("files, rig, message", [
    ([*_CAL[:2], "a/run0.mp4", "run0.pose.csv"], _TWO,
     r"rig.toml: sensor b has no recordings \(expected its videos in .*/b/\)"),
    ([*_CAL, "c/run0.mp4", "run0.pose.csv"], _TWO,
     r"/c: recordings of a sensor c that .*rig.toml does not name \(it names a, b\)"),
    ([*_CAL, "run0.mp4", "run0.pose.csv"], _TWO,
     r"run0.mp4: a rig's videos and stage logs go in its sensors' folders"),
    ([*_CAL, "a/run0.mp4", "b/run0.mp4", "a/run0.pose.csv"], _TWO,
     r"a/run0.pose.csv: a rig's pose logs are the carrier's"),
    ([*_CAL, "a/run0.mp4", "b/run0.mp4"], _TWO,
     r"a/run0.mp4: no stage log run0.stage.csv beside it and no carrier pose log"),
    ([*_CAL, "a/run0.mp4", "b/run0.mp4", "run0.pose.csv", "run9.pose.csv"], _TWO,
     r"run9.pose.csv: no sensor of .*rig.toml has a video run9.mp4"),
    ([*_CAL[2:], "a/run0.mp4", "b/run0.mp4", "run0.pose.csv"], _TWO,
     r"/a: sensor a has no calibration run"),
])  # fmt: skip
def test_a_rig_folder_that_cannot_be_run_is_named(tmp_path, capsys, files, rig, message):
    folder = _layout(tmp_path / "rec", files, rig)
    assert main(["experiment", str(folder), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("camwhisker experiment: error: ") and len(err.splitlines()) == 1
    import re

    assert re.search(message, err), err
    assert not (tmp_path / "out").exists()  # nothing written


def test_a_rig_file_given_by_option_is_the_one_used(tmp_path, capsys):
    folder = _layout(tmp_path / "rec", [*_CAL, "a/run0.mp4", "b/run0.mp4", "run0.pose.csv"],
                     _TWO)  # fmt: skip
    (tmp_path / "three.toml").write_text(_TWO + '[[sensor]]\nname = "c"\nmount = [0, 60, 0, '
                                         '1, 0, 0, 0]\n')  # fmt: skip
    assert main(["experiment", str(folder), "--out", str(tmp_path / "out"), "--rig",
                 str(tmp_path / "three.toml")]) == 2  # fmt: skip
    assert f"{tmp_path / 'three.toml'}: sensor c has no recordings" in capsys.readouterr().err


def test_a_rig_and_a_mount_together_are_refused(tmp_path, capsys):
    folder = _layout(tmp_path / "rec", [*_CAL, "a/run0.mp4", "b/run0.mp4", "run0.pose.csv"],
                     _TWO)  # fmt: skip
    assert main(["experiment", str(folder), "--out", str(tmp_path / "out"), "--mount",
                 "0,0,0,1,0,0,0"]) == 2  # fmt: skip
    assert "the rig file gives each sensor's mount; leave out --mount" in capsys.readouterr().err


# --- a simulated rig through `camwhisker experiment` ------------------------------------


def _table(path: Path, columns: dict) -> None:
    """A signal table where batch writes it, with a complete sidecar: batch reuses it."""
    write_csv(path, columns, digits=8)
    write_sidecar(path, {"frames_decoded": int(columns["t_s"].size),
                         "timings": {"seconds": 1.0}})  # fmt: skip


def _rig_folder(root: Path, runs, mounts: dict, theta_turn: dict | None = None,
                pegs=None, low_calib: Path | None = None) -> Path:
    """A rig's folder and its signal tables in ``root/out``: sensor low calibrated from its
    own peg runs ``pegs`` (or from ``low_calib``, a folder with its calib.toml), mid and
    high from the bundled calibration file."""
    folder = root / "rec"
    folder.mkdir(parents=True)
    (folder / "sensor.toml").write_text(dump_sensor(Sensor()))
    shutil.copy(SPACE / "calib.toml", folder / "calib.toml")
    shutil.copy(SPACE / "calib.mf.csv", folder / "calib.mf.csv")
    calibs = {n: "calib.toml" for n in RIG_SENSORS}
    calibs["low"] = None
    if low_calib is not None:
        shutil.copytree(low_calib, folder / "low_calib")
        calibs["low"] = "low_calib/calib.toml"
    (folder / "rig.toml").write_text(dump_rig([(n, mounts[n], None, calibs[n])
                                               for n in RIG_SENSORS]))  # fmt: skip
    signals = root / "out"
    for lr in runs:
        (folder / lr.sensor).mkdir(exist_ok=True)
        (folder / lr.sensor / f"{lr.name}.mp4").write_bytes(b"")
        cols = {k: np.asarray(lr.run.signals[k]) for k in _SIGNALS}
        if theta_turn and lr.sensor in theta_turn:  # the sensor turned on its mount
            cols["theta_deg"] = (cols["theta_deg"] + theta_turn[lr.sensor] + 180) % 360 - 180
        _table(signals / lr.sensor / "signals" / f"{lr.name}.csv", cols)
        if lr.height_mm == 0.0:
            write_csv(folder / f"{lr.name}.pose.csv", pose_columns(carrier_poses(lr)), 10)
    for run in pegs or ():
        stem = f"calibration_{run.name}"
        (folder / "low" / f"{stem}.mp4").write_bytes(b"")
        write_csv(folder / "low" / f"{stem}.stage.csv",
                  {k: run.stage[k] for k in ("t_s", "x_mm", "r_mm")}, digits=10)
        _table(signals / "low" / "signals" / f"{stem}.csv",
               {k: np.asarray(run.signals[k]) for k in _SIGNALS})
    return folder


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    sweep, runs = simulate_space_sweep("cylinder", np.random.default_rng(SEED), rig=True)
    root = tmp_path_factory.mktemp("rig")
    # Sensor low calibrated on its own eight pegs (the paper's), as a user's would be.
    folder = _rig_folder(root, runs, rig_mounts(), pegs=simulate_runs("rigid", 500))
    assert main(["experiment", str(folder), "--out", str(root / "out"), "--quiet"]) == 0
    summary = json.loads((root / "out" / "summary.json").read_text(),
                         parse_constant=lambda c: pytest.fail(f"{c}: not strict JSON"))
    return {"root": root, "runs": runs, "truth": truth_in_world(sweep), "summary": summary}


def _vec(d: dict, names) -> np.ndarray:
    return np.array([d[n] for n in names], float)


def _off_axis(centre: np.ndarray, other: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The offset between two points on cylinder axes, across the axis."""
    d = centre - other
    return d - (d @ axis) * axis


def test_the_rig_gives_one_cylinder_close_to_the_truth(rig):
    s, truth = rig["summary"], rig["truth"]
    space = s["space"]
    assert space["model"] == "cylinder"
    assert space["runs"] == [f"{n}/run{i}" for n in RIG_SENSORS for i in (0, 1)]
    p = space["params"]
    u, true_u = _vec(p, _AXIS), _vec(truth, _AXIS)
    axis_err = math.degrees(math.acos(min(1.0, abs(u @ true_u))))
    off = np.linalg.norm(_off_axis(_vec(p, _CENTRE), _vec(truth, _CENTRE), true_u))
    # This seed's rig gives 0.22 deg, 0.03 mm and +0.09 mm; the bounds leave room for the
    # contact side's changes yet fail a rig whose mounts or carrier log were mixed up (the
    # heights are 30 mm apart): 1 deg, 0.5 mm and 0.5 mm (the targets: 3 deg, 2 mm).
    assert axis_err < 1.0 and off < 0.5, (axis_err, off)
    assert abs(p["radius_mm"] - truth["radius_mm"]) < 0.5
    assert (rig["root"] / "out" / "map.ply").stat().st_size > 1000


def test_the_summary_names_each_sensor_its_mount_and_calibration(rig):
    sensors = rig["summary"]["rig"]["sensors"]
    assert [x["name"] for x in sensors] == list(RIG_SENSORS)
    for x, h in zip(sensors, HEIGHTS_MM, strict=True):
        assert x["mount"] == {"position_mm": [0.0, h, 0.0], "quat": [1.0, 0.0, 0.0, 0.0]}
    low, mid, _ = (x["calibration"] for x in sensors)
    out = rig["root"] / "out"
    assert low["file"] == str(out / "low" / "calib.toml") and low["calibration_runs"] == 8
    assert (out / "low" / "calib.toml").is_file() and not (out / "mid" / "calib.toml").exists()
    assert mid["given"] and mid["file"].endswith("rec/calib.toml")
    assert mid["calibration_runs"] == 0 and mid["gm_model"] == "beam"
    runs = rig["summary"]["runs"]
    assert len(runs) == 6 + 8 and rig["summary"]["failed"] == {}
    assert {(r["sensor"], r["role"]) for r in runs if r["log"] == "pose"} == \
        {(n, "object") for n in RIG_SENSORS}


def test_each_sensors_contacts_are_placed_by_its_own_mount(rig):
    # Each sensor's rows in W: along the axis they lie at its height (the sweeps are
    # planar in the carrier's x-z plane), so their mean along the true axis is the mount's
    # y to within the tables' 6 digits and the axis's 0.3 deg over 150 mm (about 1 mm).
    truth = rig["truth"]
    u, c = _vec(truth, _AXIS), _vec(truth, _CENTRE)
    rot = Rotation.from_quat(read_pose_log(rig["root"] / "rec" / "run0.pose.csv").quat[0],
                             scalar_first=True)  # fmt: skip
    sign = np.sign(rot.apply([0, 1, 0]) @ u)  # the carrier's y along the truth's axis
    from camwhisker.files.tables import read_columns

    for name, h in zip(RIG_SENSORS, HEIGHTS_MM, strict=True):
        t = read_columns(rig["root"] / "out" / name / "contact" / "run0.csv",
                         ("px_mm", "py_mm", "pz_mm"))  # fmt: skip
        p = np.column_stack([t["px_mm"], t["py_mm"], t["pz_mm"]])
        p = p[np.isfinite(p).all(axis=1)]
        assert p.shape[0] > 20
        along = sign * (p - c) @ u
        assert abs(np.median(along) - h) < 1.0, (name, np.median(along))


def _rerun(rig, tmp_path, mounts, theta_turn=None) -> dict:
    """The rig's experiment again with other mounts (and turned sensors): its percept."""
    low = tmp_path / "low_calib"
    low.mkdir()
    for f in ("calib.toml", "calib.mf.csv"):  # low's calibration from the first run: the same
        shutil.copy(rig["root"] / "out" / "low" / f, low / f)
    folder = _rig_folder(tmp_path, rig["runs"], mounts, theta_turn, low_calib=low)
    s = run_experiment(folder, tmp_path / "out", progress=False, plots=False)
    return s["space"]["params"]


def test_a_wrong_mount_moves_the_object_by_the_mounts_offset(rig, tmp_path):
    # Every mount 7 mm further along the carrier's x and 4 along its z: the same contacts,
    # shifted rigidly by the carrier's rotation of (7, 0, 4) mm, give the same cylinder so
    # shifted (across its axis). Within 0.02 mm: the tables' 6 printed digits.
    shift = np.array([7.0, 0.0, 4.0])
    mounts = {n: (m[0] + shift[0], m[1], m[2] + shift[2], *m[3:]) for n, m in rig_mounts().items()}
    p = _rerun(rig, tmp_path, mounts)
    q = rig["summary"]["space"]["params"]
    u = _vec(q, _AXIS)
    rot = Rotation.from_quat(read_pose_log(rig["root"] / "rec" / "run0.pose.csv").quat[0],
                             scalar_first=True)  # fmt: skip
    want = _off_axis(rot.apply(shift), np.zeros(3), u)
    got = _off_axis(_vec(p, _CENTRE), _vec(q, _CENTRE), u)
    assert np.linalg.norm(want) > 7.0  # a shift that a percept without mounts would miss
    assert np.linalg.norm(got - want) < 0.02, (got, want)
    assert abs(p["radius_mm"] - q["radius_mm"]) < 0.02


def test_a_sensor_turned_on_its_mount_gives_the_same_object(rig, tmp_path):
    # Sensor high mounted turned half a turn about its shaft (z_S): its x_S and y_S point
    # the other way, so its theta reads 180 deg more for the same push. Its mount's
    # rotation turns it back: the same cylinder within the tables' digits (0.02 mm, 0.01
    # deg).
    mounts = dict(rig_mounts())
    mounts["high"] = (0.0, 30.0, 0.0, 0.0, 0.0, 0.0, 1.0)
    p = _rerun(rig, tmp_path, mounts, theta_turn={"high": 180.0})
    q = rig["summary"]["space"]["params"]
    u = _vec(q, _AXIS)
    assert math.degrees(math.acos(min(1.0, abs(_vec(p, _AXIS) @ u)))) < 0.01
    assert np.linalg.norm(_off_axis(_vec(p, _CENTRE), _vec(q, _CENTRE), u)) < 0.02
    assert abs(p["radius_mm"] - q["radius_mm"]) < 0.02


# --- the simulator as a rig -------------------------------------------------------------


def test_simulate_space_as_a_rig_writes_the_carriers_log_and_each_sensors_table(tmp_path):
    assert main(["dev", "simulate-space", "--kind", "cylinder", "--seed", "1", "--rig",
                 "--out", str(tmp_path)]) == 0  # fmt: skip
    rig = read_rig(tmp_path / "rig.toml")
    assert rig.names == list(RIG_SENSORS)
    assert sorted(p.name for p in tmp_path.glob("*.pose.csv")) == ["run0.pose.csv",
                                                                    "run1.pose.csv"]
    _, runs = simulate_space_sweep("cylinder", np.random.default_rng(1), rig=True)
    for lr in runs:
        assert (tmp_path / lr.sensor / f"{lr.name}.signals.csv").is_file()
        # The carrier's log with the sensor's mount is the sensor's own pose: within the
        # log's 9 significant digits (0.001 mm at 300 mm).
        s = read_pose_log(tmp_path / f"{lr.name}.pose.csv",
                          rig.sensors[RIG_SENSORS.index(lr.sensor)].mount)  # fmt: skip
        assert np.max(np.abs(s.p_mm - lr.poses[1])) < 2e-3
        assert np.max(np.abs(s.quat - lr.poses[2])) < 1e-8


def test_simulate_space_without_rig_still_writes_the_bundled_sample(tmp_path):
    assert main(["dev", "simulate-space", "--kind", "cylinder", "--seed", "1", "--out",
                 str(tmp_path)]) == 0  # fmt: skip
    tables = sorted(SPACE.glob("h*.csv"))
    assert len(tables) == 12
    for f in tables:
        assert (tmp_path / f.name).read_bytes() == f.read_bytes(), f.name
    made, bundled = (json.loads(p.read_text()) for p in (tmp_path / "object.json",
                                                         SPACE / "object.json"))
    made.pop("command"), bundled.pop("command")
    assert made == bundled
