"""camwhisker dev bench: the machinery on a tiny clip, the Pareto front, the table.

The clip is the nominal scene's first 6 frames (seed 2001): rest frames and
the first hold. Bounds: the default front end's phi RMSE there is ~0.017 deg
(0.05 deg allows for platform differences; a broken tracker is off by degrees).
"""

from __future__ import annotations

import numpy as np
import pytest

from camwhisker.bench.configs import CONFIGS, DEFAULT, select
from camwhisker.bench.pareto import pareto_front
from camwhisker.bench.peers import parabolic_peak

DEFAULT_PHI_RMSE_MAX_DEG = 0.05


def test_pareto_front_hand_made():
    # speed, error: A fast and bad, B slow and good, C dominated by D, D, E tie with D
    speed = np.array([100.0, 5.0, 20.0, 30.0, 30.0, np.nan])
    error = np.array([1.0, 0.01, 0.5, 0.4, 0.4, 0.001])
    front = pareto_front(speed, error)
    assert front.tolist() == [True, True, False, True, True, False]


def test_pareto_front_strict_domination():
    # equal speed, lower error dominates; equal in both: neither dominates
    assert pareto_front(np.array([10.0, 10.0]), np.array([0.2, 0.1])).tolist() == [False, True]
    assert pareto_front(np.array([10.0, 10.0]), np.array([0.1, 0.1])).tolist() == [True, True]


def test_pareto_front_speed_tolerance():
    # 104 against 100 frames/s is a tie within 5 %: equal error no longer dominates
    speed = np.array([100.0, 104.0, 120.0, 110.0])
    error = np.array([0.1, 0.1, 0.2, 0.05])
    assert pareto_front(speed, error).tolist() == [False, False, True, True]
    assert pareto_front(speed[:3], error[:3], speed_tol=0.05).tolist() == [True, True, True]
    # a more accurate point within the tolerance still dominates a slightly faster one
    assert pareto_front(speed, error, speed_tol=0.05).tolist() == [False, False, True, True]


def test_pareto_front_several_error_axes():
    # B is more accurate in phi, A in dz: neither dominates; C is worse in both than A
    speed = np.array([100.0, 100.0, 100.0])
    error = np.array([[0.015, 0.006], [0.014, 0.008], [0.016, 0.007]])
    assert pareto_front(speed, error).tolist() == [True, True, False]
    # one axis alone: B dominates A and C
    assert pareto_front(speed, error[:, 0]).tolist() == [False, True, False]
    assert not pareto_front(speed, np.array([[0.1, np.nan], [0.2, 0.1], [0.3, 0.2]]))[0]
    # within an error tolerance of 1 %, 0.01500 and 0.01499 are one error: a tie
    tie = np.array([[0.01500, 0.006], [0.01499, 0.006]])
    assert pareto_front(speed[:2], tie).tolist() == [False, True]
    assert pareto_front(speed[:2], tie, error_tol=0.01).tolist() == [True, True]


def test_timing_spread_from_repeats():
    from camwhisker.bench.run import SceneResult, timing_spread

    def res(config, scene, lo, hi):
        return SceneResult(config, scene, 10, lo, lo, 0.0, 0.0, 1.0, 0.01, 0.01, 0.01, 1e-4,
                           1e-5, hi)  # fmt: skip

    rs = [res("a", "n", 1.0, 1.1), res("a", "d", 1.0, 1.0), res("b", "n", 2.0, 2.6),
          res("c", "n", 1.0, 1.2), res("d", "n", 9.0, 9.0)]  # fmt: skip
    # a: 2.1 / 2.0 - 1, b: 0.3, c: 0.2; d was timed once and does not count: median 0.2
    assert timing_spread(rs) == pytest.approx(0.2)
    assert timing_spread([res("a", "n", 1.0, float("nan"))]) == 0.0


def test_parabolic_peak_sub_pixel():
    x = np.arange(9.0)
    score = -((x[None, :] - 4.3) ** 2) - (x[:, None] - 2.8) ** 2
    u, v, _ = parabolic_peak(score.astype(np.float32))
    assert u == pytest.approx(4.3, abs=1e-4) and v == pytest.approx(2.8, abs=1e-4)


def test_select_configs():
    assert [c.name for c in select(None)] == [c.name for c in CONFIGS]
    with pytest.raises(ValueError, match="unknown configuration"):
        select("default,nope")


def test_bench_tiny_clip(tmp_path):
    from camwhisker.bench.run import load_scene, markdown, plot, run_benchmark

    configs = select(f"{DEFAULT},peer: matchTemplate")
    scene = load_scene("nominal", 6, tmp_path / "cache")
    assert len(scene.frames) == 6
    # repeats=2: timed twice in turn, errors checked to repeat exactly
    results = run_benchmark(configs, ["nominal"], 6, tmp_path / "cache", repeats=2)
    # every configuration processed the same frames (all but the rest frame)
    assert [r.frames for r in results] == [5, 5]
    default = results[0]
    assert default.ok == 1.0
    assert default.phi_rmse_deg < DEFAULT_PHI_RMSE_MAX_DEG
    assert default.cpu_s > 0 and default.phi_bound_deg > 0
    text = markdown(results, configs, "camwhisker dev bench --test", {"cpu": "x", "cores": 2,
                    "load": (0.0, 0.0, 0.0)}, 1.0, 6)  # fmt: skip
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| configuration |"))
    table = lines[start : lines.index("", start)]
    assert len(table) == 2 + len(configs)
    assert table[2].startswith("| default |") and table[3].startswith("| peer: matchTemplate |")
    png = plot(results, configs, tmp_path / "b.png")
    assert png.stat().st_size > 1000


def test_cli_bench_rejects_unknown(tmp_path, capsys):
    from camwhisker.cli import main

    assert main(["dev", "bench", "--out", str(tmp_path / "b.md"), "--configs", "nope"]) == 2
    assert "unknown configuration" in capsys.readouterr().err


def test_library_imports_no_benchmark_command_line_or_renderer():
    # bench/ and the CLI sit on top of the library; the simulators (sim/) are for them and
    # the tests, never for the per-frame path (tests/test_layout.py holds the whole rule).
    import ast
    from pathlib import Path

    import camwhisker

    root = Path(camwhisker.__file__).parent
    above = ("camwhisker.bench", "camwhisker.cli", "camwhisker.sim")
    found = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root)
        if rel.parts[0] in ("bench", "cli", "sim"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([node.module or ""] if isinstance(node, ast.ImportFrom)
                     else [a.name for a in node.names] if isinstance(node, ast.Import) else [])
            found += [f"{rel}: {n}" for n in names if n.startswith(above)]
    assert len(list(root.rglob("*.py"))) > 50  # the package was found
    assert found == []


def test_calibration_table_and_summary_on_made_up_rows():
    from camwhisker.bench.calibration import (
        CalibrationRow,
        outside_3se,
        summary,
        table,
        within_3se,
    )
    from camwhisker.bench.reality import RealityRow
    from camwhisker.sensor.model import GEOMETRY_NAMES

    def row(label, ok, phi, dz):
        return RealityRow(100, label, True, ok, phi, dz)

    share, n = within_3se(np.array([1.0, 2.0, 3.0]), np.array([0.1, np.nan, 0.1]),
                          np.array([1.2, 9.0, 3.5]))  # fmt: skip
    assert (share, n) == (0.5, 2)
    good = CalibrationRow(100, row("nominal", 0.5, 0.3, 0.02), row("fitted", 1.0, 0.03, 0.012),
                          row("true", 1.0, 0.02, 0.01), 1.0, 20, 41.0, phi_se_deg=0.01,
                          phi_error_deg=0.02)  # fmt: skip
    nan = float("nan")
    failed = CalibrationRow(101, row("nominal", 0.5, 0.3, 0.02), None,
                            row("true", 1.0, 0.02, 0.01), nan, 0, 3.0, "no fit")  # fmt: skip
    text = table([good, failed])
    lines = text.splitlines()
    assert len(lines) == 4 and all(line.count("|") == lines[0].count("|") for line in lines)
    assert "| 1.50 | 1.20 | 100% of 20 | 0.0200 / 0.0100 | - | 41 |" in lines[2]
    assert "| - | - | - |" in lines[3] and "no fit" in lines[3]
    assert good.meets() == {"phi": True, "dz": True, "ok": True, "se": True}
    assert not any(failed.meets().values())
    half = CalibrationRow(102, row("nominal", 0.5, 0.3, 0.02), row("fitted", 1.0, 0.03, 0.012),
                          row("true", 1.0, 0.02, 0.01), 0.5, 4, 40.0, "",
                          ("camera.k1", "plate.h_r_mm"), 0.01, 0.05)  # fmt: skip
    first, gains, pooled, phi = summary([good, failed, half]).splitlines()
    assert first.endswith("all 1/3")
    assert gains.endswith("within 3 reported SE: 0/2")  # neither row has a gain
    assert "builds pooled: 22/24" in pooled and "camera.k1 1, plate.h_r_mm 1" in pooled
    assert phi.endswith("within 3 reported SE: 1/2")  # 0.02 within 0.03, 0.05 not
    # With known dz steps: dz within 1.2x (here 1.15) and the gain within 0.3 %.
    steps = CalibrationRow(103, row("nominal", 0.5, 0.3, 0.02), row("fitted", 1.0, 0.03, 0.0115),
                           row("true", 1.0, 0.02, 0.01), 1.0, 20, 41.0, gain_error=0.0025,
                           gain_se=0.001, dz_steps=True)  # fmt: skip
    assert steps.meets() == {"phi": True, "dz": True, "ok": True, "se": True, "gain": True}
    assert "+0.25 / 0.10" in table([steps])
    assert "dz gain within 0.3 % 1/1" in summary([steps])
    value, se = np.zeros(len(GEOMETRY_NAMES)), np.full(len(GEOMETRY_NAMES), 0.1)
    truth, se[2] = value + 0.25, np.nan  # 2.5 SE off, one held
    truth[[1, 2]] = 0.35  # 3.5 SE off, and held
    assert outside_3se(value, se, truth) == (GEOMETRY_NAMES[1],)


def test_reality_summary_counts_each_limit_on_made_up_rows():
    """The reality bench's summary: each limit counted over the rows it concerns."""
    from camwhisker.bench.reality import RealityRow, closing_rest, summary, table
    from camwhisker.sim.render.scenarios import make_scenario

    def row(seed, label, bias15=0.0, bias30=0.0, zero=0.0, warned=False):
        return RealityRow(seed, label, True, 1.0, 0.02, 0.005, "", bias15, bias30, zero, 0.002,
                          30, warned, 0.1)  # fmt: skip

    rows = [row(100, "true", bias15=0.019, bias30=-0.041, zero=0.0009),  # 30 deg over, zero ok
            row(100, "true, 1 rest frame", zero=0.0011),  # the zero over half the noise
            row(100, "nominal", warned=True),
            row(101, "true"), row(101, "true, 1 rest frame"), row(101, "nominal"),
            row(5000, "nominal render", warned=True)]  # fmt: skip
    effects = {100: 0.3, 101: 0.02}  # 101's deviation moves phi at 20 deg too little to warn
    text = summary(rows, effects)
    assert "<= 0.02: 2/2; |phi bias > 30 deg| <= 0.04: 1/2" in text
    assert "rest averaged 2/2, one rest frame 1/2" in text
    assert "by > 0.05 deg 1/1, where it does not 0/1; true file 0/2; nominal renders 1/1" in text
    lines = table(rows, effects).splitlines()
    assert len(lines) == 9 and all(line.count("|") == lines[0].count("|") for line in lines)
    track = make_scenario("rest_bracketed", 150, 3).track
    closing = closing_rest(track)
    assert closing.sum() >= 30 and closing[-1] and not closing[:30].any()
    assert (track.phi_deg[closing] == 0).all() and (track.phi_deg[:30] == 0).all()
