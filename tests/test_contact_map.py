"""The contact map (docs/map.md): points in W as PLY, a voxel grid of belief, the command.

Hand values: a Gaussian of sigma 20 mm on 10 mm voxels puts the voxel centres nearest a
lone point 5 mm off it along each axis (the grid starts 3 sigma = 60 mm, six voxels, below
it), so the peak is exp(-75 / 800). Contact tables come as in test_space.py: simulated
rigid-peg stage runs given as pose logs in a turned and shifted world frame.
"""

from __future__ import annotations

import argparse
import json
import math
import re

import numpy as np
import plyfile
import pytest
from scipy.spatial.transform import Rotation

from camwhisker.cli import main
from camwhisker.cli import map as map_cli
from camwhisker.cli.common import INPUT_ERRORS, HelpFormatter
from camwhisker.contact.calibrate import read_calibration
from camwhisker.contact.space import contact_rows_in_space
from camwhisker.contact.stage import read_stage_log
from camwhisker.files.tables import read_columns, write_csv
from camwhisker.io.poses import pose_log_from_arrays
from camwhisker.io.signals import read_signal_table
from camwhisker.percept import contact_map as cm

CAL_RUNS = ("r22.5", "r27.5", "r33.5", "r42.5", "r50", "r60", "r72.5", "r90")
RUNS = ("r33.5", "r60")
R0 = Rotation.from_euler("zyx", [35.0, -20.0, 50.0], degrees=True)
P0 = np.array([120.0, -40.0, 300.0])
#: float32 keeps 24 bits: half a step at 512 mm is 3.1e-5 mm (the sim's points lie under 400).
FLOAT32_MM = 3.1e-5
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    """Two contact tables with the world columns, and the calibration's folder."""
    root = tmp_path_factory.mktemp("map")
    for name, seed in (("cal", "24"), ("run", "23")):
        assert main(["dev", "simulate-stage", "--kind", "rigid", "--out", f"{root}/{name}",
                     "--seed", seed]) == 0  # fmt: skip
    args = ["calibrate", "--out", f"{root}/calib.toml"]
    for r in CAL_RUNS:
        args += ["--signals", f"{root}/cal/{r}_signals.csv", "--stage", f"{root}/cal/{r}_stage.csv"]
    assert main(args) == 0
    calib = read_calibration(root / "calib.toml")
    paths = []
    for name in RUNS:
        log = read_stage_log(root / "run" / f"{name}_stage.csv")
        local = np.column_stack([log.x_mm, 0 * log.x_mm, 0 * log.x_mm])
        q = np.tile(R0.as_quat(scalar_first=True), (log.t_s.size, 1))
        poses = pose_log_from_arrays(log.t_s, P0 + R0.apply(local), q, f"{name} poses")
        cols, _, _ = contact_rows_in_space(read_signal_table(root / "run" / f"{name}_signals.csv"),
                                           poses, calib)  # fmt: skip
        write_csv(root / f"{name}_contacts.csv", cols)
        paths.append(root / f"{name}_contacts.csv")
    return paths


def _points(p_mm, belief, t_s=None) -> cm.ContactPoints:
    p = np.asarray(p_mm, float).reshape(-1, 3)
    n = p.shape[0]
    return cm.ContactPoints(p_mm=p, normal=np.tile([1.0, 0.0, 0.0], (n, 1)),
                            belief=np.asarray(belief, float), z_score=np.zeros(n),
                            r_sd_mm=np.ones(n), t_s=np.zeros(n) if t_s is None else
                            np.asarray(t_s, float), table=np.zeros(n, int),
                            row=np.arange(n), sources=("hand",), eta_deg=1.5)  # fmt: skip


def _run(argv, capsys=None) -> int:
    """``camwhisker map ...`` through a parser made here, handling errors as main() does."""
    parser = argparse.ArgumentParser(prog="camwhisker")
    sub = parser.add_subparsers(dest="command", required=True)
    map_cli.add_map(sub)
    for command in sub.choices.values():
        command.formatter_class = HelpFormatter
    args = parser.parse_args(["map", *argv])
    try:
        return int(args.func(args) or 0)
    except INPUT_ERRORS as exc:
        print(f"camwhisker map: error: {exc}")
        return 2


# ------------------------------------------------------------------ points


def test_r_spread_combines_gm_and_mf_by_inverse_variance():
    # 1 / sqrt(1/9 + 1/16) = 12 / 5; a missing or zero sigma adds nothing.
    got = cm.r_sd_mm([3.0, 3.0, np.nan, 0.0], [4.0, np.nan, np.nan, 4.0])
    np.testing.assert_allclose(got[[0, 1, 3]], [2.4, 3.0, 4.0], rtol=1e-12)
    assert np.isnan(got[2])


def test_points_are_the_rows_with_a_world_point(tables):
    points = cm.read_contact_points(tables)
    n = [int(np.isfinite(np.column_stack([read_columns(t, ("px_mm", "py_mm", "pz_mm"))[c]
                                          for c in ("px_mm", "py_mm", "pz_mm")])).all(axis=1)
             .sum()) for t in tables]  # fmt: skip
    assert points.n == sum(n) and n[0] > 500 and n[1] > 1000
    assert np.bincount(points.table).tolist() == n
    # Eq. 1 with the default eta 1.5 deg: b = 1 from phi = 3 deg, 0 up to 1.5 deg.
    assert cm.DEFAULT_ETA_DEG == 1.5
    own = np.concatenate([read_columns(t, ("phi_deg",))["phi_deg"][points.row[points.table == i]]
                          for i, t in enumerate(tables)])  # fmt: skip
    np.testing.assert_allclose(points.belief, np.clip(own / 1.5 - 1.0, 0.0, 1.0), rtol=0,
                               atol=1e-15)  # fmt: skip
    np.testing.assert_allclose(np.linalg.norm(points.normal, axis=1), 1.0, atol=1e-5)


def test_ply_read_back_by_plyfile_equals_the_points(tables, tmp_path):
    points = cm.read_contact_points(tables)
    cm.write_ply(tmp_path / "m.ply", points, comments=["two\nlines"])
    ply = plyfile.PlyData.read(str(tmp_path / "m.ply"))
    assert ply.elements[0].name == "vertex" and not ply.text and ply.byte_order == "<"
    v = ply["vertex"].data
    assert v.dtype.names == tuple(name for name, _ in cm.PLY_PROPERTIES)
    assert len(v) == points.n
    for k, name in enumerate("xyz"):
        assert np.max(np.abs(v[name] - points.p_mm[:, k])) <= FLOAT32_MM, name
        assert np.array_equal(v[name], points.p_mm[:, k].astype(np.float32)), name
    np.testing.assert_array_equal(v["t_s"], points.t_s)  # double: exact
    np.testing.assert_array_equal(v["table"], points.table)
    for name in ("belief", "z_score", "r_sd_mm", "nx"):
        want = {"nx": points.normal[:, 0]}.get(name, getattr(points, name, None))
        np.testing.assert_array_equal(v[name], want.astype(np.float32))  # NaN where NaN
    assert np.isnan(v["z_score"]).sum() == np.isnan(points.z_score).sum() > 0
    assert any("two lines" in c for c in ply.comments)


# ------------------------------------------------------------------ grid


def test_a_lone_point_peaks_at_the_hand_value():
    grid = cm.belief_grid(_points([[3.0, -7.0, 11.0]], [1.0]), voxel_mm=10.0, sigma_mm=20.0)
    assert grid.belief.shape == (12, 12, 12)  # 2 x 60 mm of padding in 10 mm voxels
    np.testing.assert_allclose(grid.origin_mm, [3.0 - 60, -7.0 - 60, 11.0 - 60], atol=1e-12)
    # float32 storage: a relative step of 6e-8.
    assert grid.belief.max() == pytest.approx(math.exp(-75.0 / 800.0), rel=1e-6)
    assert (grid.belief == grid.belief.max()).sum() == 8  # the 8 centres 5 mm off per axis


def test_the_grid_is_the_formula_at_every_voxel_in_small_chunks(monkeypatch):
    # Chunks of 50 elements force one point and one x slab at a time.
    rng = np.random.default_rng(5)
    p, b = rng.uniform(-40, 40, (9, 3)), rng.uniform(0, 1, 9)
    monkeypatch.setattr(cm, "CHUNK_ELEMENTS", 50)
    grid = cm.belief_grid(_points(p, b), voxel_mm=7.0, sigma_mm=12.0)
    c = np.stack(np.meshgrid(*(grid.centres_mm(a) for a in range(3)), indexing="ij"), -1)
    d2 = ((c[None] - p[:, None, None, None]) ** 2).sum(-1)
    want = (b[:, None, None, None] * np.exp(-d2 / (2 * 12.0**2))).max(axis=0)
    np.testing.assert_allclose(grid.belief, want, rtol=1e-6, atol=1e-30)  # float32


def test_two_points_take_the_max_not_the_sum():
    grid = cm.belief_grid(_points([[0.0, 0, 0], [40.0, 0, 0]], [1.0, 0.5]), 10.0, 20.0)
    x, y = grid.centres_mm(0), grid.centres_mm(1)
    i15, i35 = int(np.argmin(abs(x - 15))), int(np.argmin(abs(x - 35)))
    j = int(np.argmin(abs(y - 5)))
    assert (x[i15], x[i35], y[j]) == (15.0, 35.0, 5.0)
    # At (15, 5, 5): A 275 mm^2 away, B 675; at (35, 5, 5): A 1275, B 75 (b = 0.5).
    a15, b15 = math.exp(-275 / 800), 0.5 * math.exp(-675 / 800)
    a35, b35 = math.exp(-1275 / 800), 0.5 * math.exp(-75 / 800)
    assert grid.belief[i15, j, j] == pytest.approx(max(a15, b15), rel=1e-6)  # 0.709, not 0.924
    assert grid.belief[i35, j, j] == pytest.approx(max(a35, b35), rel=1e-6)  # 0.455, not 0.658
    assert (a15 + b15) - grid.belief[i15, j, j] > 0.2


def test_memory_keeps_only_the_last_seconds_points():
    points = _points([[0.0, 0, 0], [500.0, 0, 0], [1000.0, 0, 0]], [1, 1, 1], t_s=[0, 5, 10])
    last = cm.belief_grid(points, memory_s=2.0)
    assert last.n_points == 1 and last.t_last_s == 10.0
    np.testing.assert_allclose(last.origin_mm, [1000 - 75.0, -75.0, -75.0], atol=1e-12)
    assert last.belief.shape == (15, 15, 15)  # 150 mm of box in 10 mm voxels: the old ones out
    assert cm.belief_grid(points, memory_s=5.0).n_points == 2  # t >= 10 - 5: inclusive
    assert cm.belief_grid(points).n_points == 3


def test_the_grid_holds_every_point_with_three_sigma_to_spare(tables):
    points = cm.read_contact_points(tables)
    grid = cm.belief_grid(points)
    pad = 3 * cm.SIGMA_MM
    np.testing.assert_allclose(points.p_mm.min(axis=0) - grid.origin_mm, pad, atol=1e-9)
    above = grid.upper_mm - points.p_mm.max(axis=0)
    assert np.all(above >= pad - 1e-9) and np.all(above < pad + cm.VOXEL_MM)
    # Each point's own voxel holds at least its belief times the farthest centre's share,
    # half a voxel's diagonal away: exp(-75 / 1250) = 0.942.
    idx = np.floor((points.p_mm - grid.origin_mm) / grid.voxel_mm).astype(int)
    own = grid.belief[idx[:, 0], idx[:, 1], idx[:, 2]]
    assert np.all(own >= points.belief * math.exp(-75.0 / 1250.0) * (1 - 1e-6))


# ------------------------------------------------------------------ percept outlines


def test_outlines_of_each_model():
    sphere = cm.PerceptShape("sphere", {"center_x_mm": 1.0, "center_y_mm": 2.0,
                                        "center_z_mm": 3.0, "radius_mm": 40.0}, "s")  # fmt: skip
    (circle,) = cm.object_lines(sphere, np.zeros((1, 3)), view=2)
    np.testing.assert_allclose(np.hypot(circle[:, 0] - 1, circle[:, 1] - 2), 40.0, atol=1e-9)
    cyl = cm.PerceptShape("cylinder", {"center_x_mm": 0.0, "center_y_mm": 0.0, "center_z_mm": 0.0,
                                       "axis_x": 0.0, "axis_y": 0.0, "axis_z": 2.0,
                                       "radius_mm": 15.0}, "c")  # fmt: skip
    pts = np.array([[0.0, 0, -30], [0.0, 0, 50]])
    sides = cm.object_lines(cyl, pts, view=0)[-2:]  # seen along x: the sides at y = +-15
    assert sorted(s[0, 1] for s in sides) == pytest.approx([-15.0, 15.0], abs=1e-12)
    assert [s[:, 2].tolist() for s in sides] == [[-30.0, 50.0]] * 2  # the points' stretch
    plane = cm.PerceptShape("plane", {"normal_x": 0.0, "normal_y": 3.0, "normal_z": 4.0,
                                      "distance_mm": 50.0}, "p")  # fmt: skip
    lines = np.concatenate(cm.object_lines(plane, np.array([[0.0, 0, 0], [20, 30, 40]])))
    np.testing.assert_allclose(lines @ [0, 0.6, 0.8], 10.0, atol=1e-9)  # n.p = 50 / |n|


# ------------------------------------------------------------------ the command


def _strict(text: str):
    def refuse(name):
        raise ValueError(f"not strict JSON: {name}")

    return json.loads(text, parse_constant=refuse)


def test_map_command_writes_four_files(tables, tmp_path, capsys):
    percept = tmp_path / "p.json"
    percept.write_text(json.dumps({"model": "sphere", "params": {
        "center_x_mm": 100.0, "center_y_mm": -82.0, "center_z_mm": 336.0, "radius_mm": 20.0},
        "intervals_95": {}}))  # fmt: skip
    argv = ["--out", str(tmp_path / "m.json"), "--percept", str(percept), "--memory-s", "1"]
    for t in tables:
        argv += ["--contacts", str(t)]
    assert _run(argv) == 0
    out = capsys.readouterr().out
    assert "contact points from 2 table(s)" in out and "wrote " in out
    record = _strict((tmp_path / "m.json").read_text())
    points = cm.read_contact_points(tables)
    assert record["points"]["n"] == points.n
    assert [i["points"] for i in record["inputs"]] == np.bincount(points.table).tolist()
    assert record["points"]["in_grid"] == int((points.t_s >= points.t_s.max() - 1.0).sum())
    assert 0 < record["points"]["in_grid"] < points.n
    assert record["options"] == {"voxel_mm": 10.0, "sigma_mm": 25.0, "memory_s": 1.0,
                                 "eta_deg": 1.5}  # fmt: skip
    assert all(len(i["sha256"]) == 64 for i in record["inputs"])
    assert record["percept"]["model"] == "sphere"
    ply = plyfile.PlyData.read(str(tmp_path / "m.ply"))
    assert len(ply["vertex"].data) == points.n
    with np.load(tmp_path / "m.npz", allow_pickle=False) as z:
        assert list(z["belief"].shape) == record["grid"]["shape"] and z["belief"].dtype == "f4"
        assert float(z["belief"].max()) == pytest.approx(record["grid"]["max_belief"], abs=1e-7)
        assert float(z["voxel_mm"]) == 10.0 and float(z["sigma_mm"]) == 25.0
        assert _strict(str(z["provenance"]))["n_points"] == record["points"]["in_grid"]
        np.testing.assert_allclose(z["origin_mm"], record["bounds_mm"]["grid_origin"])
    png = (tmp_path / "m.png").read_bytes()
    assert png.startswith(PNG_SIGNATURE) and len(png) > 10_000


def _contacts_args(tables) -> list[str]:
    return [a for t in tables for a in ("--contacts", str(t))]


def test_a_table_without_world_columns_is_named_and_nothing_written(tables, tmp_path, capsys):
    header, *rows = tables[0].read_text().splitlines()
    names = header.split(",")
    keep = [i for i, n in enumerate(names) if n not in ("px_mm", "py_mm", "pz_mm")]
    flat = tmp_path / "flat.csv"
    flat.write_text("\n".join(",".join(r.split(",")[i] for i in keep) for r in [header, *rows]))
    assert _run(["--contacts", str(tables[1]), "--contacts", str(flat),
                 "--out", str(tmp_path / "m")]) == 2  # fmt: skip
    assert (f"{flat} has no px_mm column: contact tables from `camwhisker contact --pose` "
            "have them") in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flat.csv"]


def test_a_table_without_a_point_says_so(tables, tmp_path, capsys):
    lines = tables[0].read_text().splitlines()
    before = tmp_path / "before.csv"  # the rows before the whisker touches: no point
    px = lines[0].split(",").index("px_mm")
    before.write_text("\n".join([lines[0], *(r for r in lines[1:] if r.split(",")[px] == "")]))
    assert _run(["--contacts", str(before), "--out", str(tmp_path / "m")]) == 2
    assert "before.csv: no contact point: no row has px_mm" in capsys.readouterr().out
    assert not list(tmp_path.glob("m.*"))


@pytest.mark.parametrize("option, message", [
    (["--voxel-mm", "0"], "--voxel-mm 0: must be a finite number > 0"),
    (["--sigma-mm", "-1"], "--sigma-mm -1: must be a finite number > 0"),
    (["--eta-deg", "nan"], "--eta-deg nan: must be a finite number > 0"),
    (["--memory-s", "-0.5"], "--memory-s -0.5: must be a finite number >= 0"),
    (["--voxel-mm", "0.01"], "voxel_mm 0.01: .* makes \\d+ x \\d+ x \\d+ voxels, more than "
                             "20,000,000: take larger voxels"),
])
def test_a_bad_option_is_named_and_nothing_written(tables, tmp_path, capsys, option, message):
    assert _run([*_contacts_args(tables), "--out", str(tmp_path / "m"), *option]) == 2
    assert re.search(message, capsys.readouterr().out)
    assert not list(tmp_path.iterdir())


def test_a_bad_percept_file_is_named_and_nothing_written(tables, tmp_path, capsys):
    bad = tmp_path / "p.json"
    bad.write_text(json.dumps({"model": "sphere", "params": {"center_x_mm": 1.0}}))
    assert _run([*_contacts_args(tables), "--out", str(tmp_path / "m"), "--percept",
                 str(bad)]) == 2  # fmt: skip
    assert f"{bad}: sphere param center_y_mm: None, expected a number" in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.json"]
