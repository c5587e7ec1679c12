"""The README's example in space, on the bundled sample: contact --pose per run, percept
and map, against the simulator's object in sample_frames/space/object.json."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from camwhisker.cli import main

SPACE = Path(__file__).resolve().parents[1] / "sample_frames" / "space"


def _vec(d: dict, names) -> np.ndarray:
    return np.array([d[n] for n in names], float)


def _perceive(folder: Path, tmp_path: Path) -> tuple[list[str], list[str], dict, dict]:
    """The README's commands on a bundled sample: contact --pose per run (pause medians),
    then percept on all the tables. Returns the runs, the --contacts arguments, the fit and
    the sample's true object."""
    runs = sorted(p.name.removesuffix(".signals.csv") for p in folder.glob("*.signals.csv"))
    for n in runs:
        assert main(["contact", "--signals", str(folder / f"{n}.signals.csv"), "--pose",
                     str(folder / f"{n}.pose.csv"), "--calib", str(SPACE / "calib.toml"),
                     "--per", "pause", "--out", str(tmp_path / f"{n}.csv")]) == 0
    tables = [a for n in runs for a in ("--contacts", str(tmp_path / f"{n}.csv"))]
    assert main(["percept", *tables, "--out", str(tmp_path / "object.json")]) == 0
    fit = json.loads((tmp_path / "object.json").read_text())
    return runs, tables, fit, json.loads((folder / "object.json").read_text())["object"]


def test_the_bundled_cylinder_from_space(tmp_path, capsys):
    runs, tables, fit, truth = _perceive(SPACE, tmp_path)
    assert len(runs) == 6  # both ways at three heights
    assert fit["model"] == "cylinder"
    p, axis, centre = fit["params"], ("axis_x", "axis_y", "axis_z"), ("center_x_mm",
                                                                      "center_y_mm",
                                                                      "center_z_mm")
    u, true_u = _vec(p, axis), _vec(truth, axis)
    off = _vec(p, centre) - _vec(truth, centre)
    off -= (off @ true_u) * true_u
    # The README's numbers (0.002 deg, 0.13 mm, 48.25 against 48.27 mm), with room for
    # another machine's last bits: the targets are 3 deg and 2 mm.
    assert math.degrees(math.acos(min(1.0, abs(u @ true_u)))) < 0.2
    assert np.linalg.norm(off) < 0.2
    assert abs(p["radius_mm"] - truth["radius_mm"]) < 0.2
    assert main(["map", *tables, "--percept", str(tmp_path / "object.json"), "--out",
                 str(tmp_path / "map")]) == 0
    assert "12161 contact points from 6 table(s)" in capsys.readouterr().out
    assert (tmp_path / "map.png").stat().st_size > 100_000


TAPS = SPACE.parent / "taps"


def test_the_bundled_rig_tapping_a_sphere(tmp_path, capsys):
    """The README's rig example: five sensors tap a sphere of 187.4 mm once each; their
    contacts slide from the first touch, the normals pin the sphere, the intervals hold the
    truth, and the next touch goes to the side the taps did not see."""
    runs, tables, fit, truth = _perceive(TAPS, tmp_path)
    assert runs == [f"L3s{k}" for k in range(1, 6)]
    assert fit["model"] == "sphere"
    centre = ("center_x_mm", "center_y_mm", "center_z_mm")
    # The README's numbers: centre 0.21 mm off, radius 187.2 against 187.4 mm; each inside
    # its 95 % interval (room for another machine's last bits: 0.1 mm, under the intervals'
    # half-widths of 0.11-0.39 mm).
    assert abs(np.linalg.norm(_vec(fit["params"], centre) - _vec(truth, centre)) - 0.21) < 0.1
    assert abs(fit["params"]["radius_mm"] - 187.2) < 0.1
    assert all(lo <= truth[k] <= hi for k, (lo, hi) in fit["intervals_95"].items())
    from camwhisker.files.tables import read_columns

    normals = np.vstack([np.column_stack(list(read_columns(
        tmp_path / f"{n}.csv", ("nx", "ny", "nz")).values())) for n in runs])
    seen = np.nanmean(normals, axis=0)
    touch = _vec(fit["next_touch"], ("normal_x", "normal_y", "normal_z"))
    assert touch @ seen / np.linalg.norm(seen) < 0.0  # the far side of the tapped cap
    assert main(["map", *tables, "--percept", str(tmp_path / "object.json"), "--out",
                 str(tmp_path / "map")]) == 0
    assert "2937 contact points from 5 table(s)" in capsys.readouterr().out


def test_gm_bias_only_where_gm_is(tmp_path):
    # The fusion's line through GM's bias is defined between GM's samples too; the table
    # gives it only where GM is (a per-frame run had -192 mm in an onset row without GM).
    from camwhisker.files.tables import read_columns

    out = tmp_path / "c.csv"
    assert main(["contact", "--signals", str(SPACE / "h+0run0.signals.csv"), "--pose",
                 str(SPACE / "h+0run0.pose.csv"), "--calib", str(SPACE / "calib.toml"),
                 "--out", str(out)]) == 0
    cols = read_columns(out, ("r_gm_mm", "gm_bias_mm"))
    gm, bias = cols["r_gm_mm"], cols["gm_bias_mm"]
    assert not np.isfinite(bias[~np.isfinite(gm)]).any()
    # Within the whisker's length (150 mm) wherever it is given.
    assert np.isfinite(bias).sum() > 2000 and np.nanmax(np.abs(bias)) < 150.0
