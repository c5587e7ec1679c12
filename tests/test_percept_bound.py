"""The Cramer-Rao bound on a wall's angle: against Monte Carlo, and on simulated sweeps."""

import json
import math

import numpy as np
from scipy.optimize import least_squares

from camwhisker.bench.percept_bound import line_angle_bound_deg


def test_line_angle_bound_is_the_spread_of_a_weighted_fit():
    # 25 points on a line whose normal is at 160 deg, each off along its own direction with
    # its own sigma (0.2-3 mm, as GM's stuck points and MF's sliding ones): the weighted
    # least-squares fit is efficient here, so its angle's sd over 2000 draws is the bound
    # within the draws' own error (~1.6 % for an sd) and the small-noise nonlinearity.
    rng = np.random.default_rng(4)
    t = math.radians(160.0)
    n, along_line = np.array([math.cos(t), math.sin(t)]), np.array([-math.sin(t), math.cos(t)])
    s = np.linspace(0.0, 40.0, 25)
    points = 5.0 * n + s[:, None] * along_line
    tilt = np.radians(rng.uniform(-60.0, 60.0, s.size))
    along = np.c_[np.cos(tilt), np.sin(tilt)] @ np.array([[n[0], n[1]], [-n[1], n[0]]])
    sigma = rng.uniform(0.2, 3.0, s.size)
    bound = line_angle_bound_deg(points, along, sigma, 160.0)
    sd = np.abs(along @ n) * sigma
    angles = []
    for _ in range(2000):
        p = points + (sigma * rng.standard_normal(s.size))[:, None] * along

        def res(x, p=p):
            return (p @ np.array([math.cos(x[0]), math.sin(x[0])]) - x[1]) / sd

        angles.append(least_squares(res, [t, 5.0]).x[0])
    assert abs(math.degrees(np.std(angles)) / bound - 1.0) < 0.07


def test_points_that_fix_no_line_have_no_bound():
    # One point (repeated) fixes no angle.
    assert math.isinf(line_angle_bound_deg([[0.0, 1.0]] * 3, [[0.0, 1.0]] * 3, [1.0] * 3, 90.0))


def test_a_turned_second_run_narrows_the_bound():
    from camwhisker.bench.contact import calibrate_simulated
    from camwhisker.bench.percept_bound import wall_angle_bound_deg
    from camwhisker.bench.percepts import CALIB_SEED, simulate_sweep
    from camwhisker.sim.mechanics.experiment import FRONT_END_NOISE, peg_radii
    from camwhisker.sim.mechanics.objects import draw_sweep

    # Tuning walls at the front end's target noise. The first run of 2563 slides at phi
    # 1.4-2.8 deg, where MF scatters 20-50 mm along the whisker per pause; 2000's at 6-11 deg;
    # 126's at 1.2-2.4 deg leaves no contact point after the slip. Their first runs' bounds
    # (5.77, 0.35 deg and none) are the sd no unbiased fit of those pauses beats. The second
    # run, turned steep by the first run's line (2000: the face at 83.9 deg, 8-15 deg of phi;
    # 2563: 74.5 deg, its line 7 deg off) or blind (126: 82.1 deg), brings them to 1.15,
    # 0.155 and 0.28 deg. The ranges allow the simulator's numerics to move.
    calib = calibrate_simulated(CALIB_SEED, noise=FRONT_END_NOISE, radii_mm=peg_radii(15))
    bounds = {}
    for seed in (2563, 2000, 126):
        rng = np.random.default_rng(seed)
        sweep = draw_sweep("wall", rng)
        runs = simulate_sweep(sweep, calib, rng)
        assert len(runs) == 2
        bounds[seed] = [wall_angle_bound_deg(sweep, part, calib) for part in (runs[:1], runs)]
    assert 4.0 < bounds[2563][0] < 8.0 and 0.8 < bounds[2563][1] < 1.5
    assert 0.2 < bounds[2000][0] < 0.5 and 0.1 < bounds[2000][1] < 0.2
    assert math.isinf(bounds[126][0]) and 0.15 < bounds[126][1] < 0.4


def test_percept_bench_plots_each_wall_against_its_bound(tmp_path, capsys):
    from PIL import Image

    from camwhisker.bench.percepts import plot_wall_bounds
    from camwhisker.cli import main

    # Tuning seeds 0 (a wall) and 1 (a cylinder): one wall on the plot.
    png = tmp_path / "w.png"
    assert main(["dev", "percept-bench", "--seeds", "0-1", "--calib-pegs", "15", "--plot", str(png),
                 "--out", str(tmp_path / "r.json")]) == 0
    assert "walls within 1 deg at the pauses' Cramer-Rao bound" in capsys.readouterr().out
    with Image.open(png) as im:
        assert "percept-bench --seeds 0-1" in im.info["Description"]
    # Read back from the JSON, with a wall whose bound is null (inf) left out.
    rows = json.loads((tmp_path / "r.json").read_text())["sweeps"]
    rows.append({**rows[0], "angle_bound_deg": None})
    assert plot_wall_bounds(rows, tmp_path / "again.png", "test") == 1
