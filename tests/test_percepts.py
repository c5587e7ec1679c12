"""Shape percepts: fits on synthetic surfels, model choice, the percept command, bad input,
and a few simulated sweeps of the campaign (tuning seeds)."""

import json
import math

import numpy as np
import pytest

from camwhisker.cli import main
from camwhisker.contact.fusion import KEEP_GM_POSTERIOR
from camwhisker.contact.shape import reconstruct
from camwhisker.files.tables import write_csv
from camwhisker.percept.percepts import MIN_SURFELS, fit_model, object_of, perceive
from camwhisker.percept.surfels import Pose, merge, surfels_from_columns

# Contact points scatter 0.2 mm about the surface here, as the fused points of the
# simulated box and bottle do.
NOISE_MM = 0.2


def _table(x, y, base_x=None):
    """Contact-table columns for contact points (x, y), one row per point."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    r = np.hypot(x - (base_x if base_x is not None else x), y)
    return {"t_s": np.arange(x.size) * 0.5, "x_mm": x if base_x is None else base_x,
            "phi_deg": np.degrees(np.arctan2(np.zeros(x.size), y)), "x_hat_mm": x,
            "r_hat_mm": r, "y_hat_mm": y}


def _noisy(x, y, rng):
    return x + NOISE_MM * rng.standard_normal(x.size), y + NOISE_MM * rng.standard_normal(y.size)


def _wall(rng, angle_deg=75.0, y_end=40.0, n=30):
    s = np.linspace(0.0, 50.0, n)
    a = math.radians(angle_deg)
    x, y = _noisy(s * math.cos(a), y_end + s * math.sin(a), rng)
    return surfels_from_columns(_table(x, y, base_x=np.linspace(-30.0, -20.0, n)))


def _cylinder(rng, cx=0.0, cy=60.0, radius=40.0, n=25):
    parts = []
    for i, (a0, a1) in enumerate(((180.0, 215.0), (360.0, 325.0))):
        a = np.radians(np.linspace(a0, a1, n))
        x, y = _noisy(cx + radius * np.cos(a), cy + radius * np.sin(a), rng)
        base = np.linspace(-60.0, -45.0, n) * (1 if i == 0 else -1)
        parts.append(surfels_from_columns(_table(x, y, base), table=i))
    return merge(parts)


def _corner(rng, apex=(0.0, 50.0), a1=75.0, a2=-30.0, n=25):
    parts = []
    for i, a in enumerate((a1, a2)):
        s = np.linspace(0.0, 40.0, n)
        u = math.radians(a)
        x, y = _noisy(apex[0] + s * math.cos(u), apex[1] + s * math.sin(u), rng)
        parts.append(surfels_from_columns(_table(x, y, np.full(n, -40.0)), table=i))
    return merge(parts)


def test_line_fit_recovers_the_wall():
    f = fit_model("line", _wall(np.random.default_rng(1)))
    # 30 points over 50 mm at 0.2 mm: angle SE ~0.07 deg, offset SE ~0.05 mm; 0.5 is 7 SE.
    assert f.params["angle_deg"] == pytest.approx(75.0, abs=0.5)
    assert f.params["distance_mm"] == pytest.approx(40.0 * math.cos(math.radians(75.0)), abs=0.5)


def test_circle_fit_recovers_the_cylinder_from_two_short_arcs():
    f = fit_model("circle", _cylinder(np.random.default_rng(2)))
    # Two 35-deg arcs 80 mm apart at 0.2 mm: the radius and centre to well under 1 mm.
    assert f.params["radius_mm"] == pytest.approx(40.0, abs=1.0)
    assert math.hypot(f.params["center_x_mm"], f.params["center_y_mm"] - 60.0) < 1.0


def test_corner_fit_recovers_apex_and_opening():
    f = fit_model("corner", _corner(np.random.default_rng(3)))
    # Two 40-mm faces at 0.2 mm: apex within 1 mm, opening (105 deg) within 2 deg.
    assert math.hypot(f.params["apex_x_mm"], f.params["apex_y_mm"] - 50.0) < 1.0
    assert f.params["opening_deg"] == pytest.approx(105.0, abs=2.0)


def test_corner_apex_intervals_are_never_zero_wide():
    # A contact as far from both faces switched face within the solver's Jacobian step, and
    # its direction term's jump zeroed the apex's width on 3 of these 20 corners. 25 points
    # a face at 0.2 mm give widths of 0.38-0.82 mm; under 0.3 is that fault.
    widths = []
    for seed in range(20):
        f = fit_model("corner", _corner(np.random.default_rng(seed)))
        widths += [f.intervals[k][1] - f.intervals[k][0] for k in ("apex_x_mm", "apex_y_mm")]
    assert min(widths) > 0.3


# A circle of huge radius fits a line as well as the line does: its one extra parameter
# costs ln(60 residuals) of BIC, an evidence ratio of sqrt(60) ~ 7.7 at the most; a line
# cannot bend to arcs or a corner, so there the runner-up is far behind.
@pytest.mark.parametrize("make, model, min_ratio", [(_wall, "line", 5.0),
                                                    (_cylinder, "circle", 1e3),
                                                    (_corner, "corner", 1e3)])
def test_model_choice_on_clear_cases(make, model, min_ratio):
    p = perceive(make(np.random.default_rng(4)))
    assert p.best.model == model
    assert p.evidence_ratio > min_ratio


def test_scattered_points_are_no_object():
    rng = np.random.default_rng(5)
    x, y = rng.uniform(-50, 50, 30), rng.uniform(20, 120, 30)
    order = np.argsort(y)  # directions from neighbours exist but mean nothing
    p = perceive(surfels_from_columns(_table(x[order], y[order])))
    assert p.best.model == "none"


def test_too_few_contacts_are_no_object():
    s = _wall(np.random.default_rng(6), n=MIN_SURFELS - 1)
    assert perceive(s).best.model == "none" and set(perceive(s).fits) == {"none"}
    assert object_of(perceive(s)) == f"too few contacts to tell a shape ({MIN_SURFELS - 1})"


def test_line_intervals_cover_the_truth_with_independent_noise():
    # 40 walls at 0.2 mm noise: a 95 % interval misses ~2 of 40; 30 of 40 (75 %)
    # is where a 95 % claim is clearly broken.
    hits = 0
    for seed in range(40):
        lo, hi = fit_model("line", _wall(np.random.default_rng(100 + seed))).intervals["angle_deg"]
        hits += lo <= 75.0 <= hi
    assert hits >= 34


def _estimates_table(r_hat, r_mf, p_good, mf_outside, phi_deg, base_x, sigma_mf=0.3):
    """Contact-table columns with both estimates, the fusion's P(GM good) and MF's sigma, one
    row a pause."""
    x_hat, y_hat = reconstruct(base_x, r_hat, phi_deg, 0.1 * phi_deg, 1.0)
    return {"t_s": np.arange(base_x.size) * 0.5, "x_mm": base_x, "phi_deg": phi_deg,
            "dz_pause_mm": 0.1 * phi_deg,
            "x_hat_mm": x_hat, "r_hat_mm": r_hat, "y_hat_mm": y_hat, "r_mf_mm": r_mf,
            "p_gm_good": p_good, "mf_outside": mf_outside,
            "sigma_mf_mm": np.broadcast_to(sigma_mf, base_x.shape).astype(float)}


def test_surfel_point_is_mf_where_the_fusion_dropped_gm():
    # Rows: GM kept; GM dropped; dropped but MF clamped at its table's edge; no posterior;
    # dropped but no MF.
    p_good = np.array([KEEP_GM_POSTERIOR, KEEP_GM_POSTERIOR - 0.01, 0.0, np.nan, 0.0])
    r_hat = np.array([40.0, 45.0, 50.0, 55.0, 60.0])
    r_mf = np.array([41.0, 47.0, 53.0, 57.0, np.nan])
    phi, base_x = np.array([5.0, 8.0, 11.0, 14.0, 17.0]), np.arange(5.0)
    s = surfels_from_columns(_estimates_table(r_hat, r_mf, p_good, np.array([0, 0, 1, 0, 0]),
                                              phi, base_x))
    r_used = np.array([40.0, 47.0, 50.0, 55.0, 60.0])
    # Same arithmetic (eq. 12, the pause's dz off y) on both sides: equal to rounding.
    assert np.allclose(s.xy_mm, np.c_[reconstruct(base_x, r_used, phi, 0.1 * phi, 1.0)],
                       atol=1e-9, rtol=0)
    # The point from MF's r carries sigma_MF along the whisker (from the base to the point);
    # a fused point none.
    ray = s.xy_mm[1] - [base_x[1], 0.0]
    assert np.allclose(s.spread[1], 0.3 * ray / np.hypot(*ray), atol=1e-12, rtol=0)
    assert not np.any(s.spread[[0, 2, 3, 4]])
    assert merge([s, s]).spread.shape == (10, 2)
    # Without MF's sigma a row keeps r_hat: a point must say how far it may be off.
    cols = _estimates_table(r_hat, r_mf, p_good, np.zeros(5), phi, base_x, np.nan)
    assert np.allclose(surfels_from_columns(cols).xy_mm,
                       np.c_[reconstruct(base_x, r_hat, phi, 0.1 * phi, 1.0)], atol=1e-9, rtol=0)


def test_a_slips_r_hat_is_not_taken_for_gms():
    # Three pauses, GM good by the posterior: GM's own r_hat; a slip's, GM less the slide's
    # bias line (r_hat 45 where GM says 52; the slip's line through a noisy MF can be 3-8 mm
    # off, seed 113 of the tuning sweeps); GM undefined (r_hat is then MF's own).
    p_good = np.full(3, 0.99)
    r_hat, r_mf = np.array([40.0, 45.0, 50.0]), np.array([41.0, 43.0, 50.0])
    phi, base_x = np.array([5.0, 8.0, 11.0]), np.arange(3.0)
    cols = _estimates_table(r_hat, r_mf, p_good, np.zeros(3), phi, base_x)
    cols["r_gm_mm"] = np.array([40.0, 52.0, np.nan])
    s = surfels_from_columns(cols)
    r_used = np.array([40.0, 43.0, 50.0])
    assert np.allclose(s.xy_mm, np.c_[reconstruct(base_x, r_used, phi, 0.1 * phi, 1.0)],
                       atol=1e-9, rtol=0)
    # The slip's point is MF's, with sigma_MF along the whisker; the others carry none.
    assert np.hypot(*s.spread[1]) == pytest.approx(0.3, abs=1e-12)
    assert not np.any(s.spread[[0, 2]])


def _slide(angle_deg, y_end, n, length, lag_mm):
    """A contact sliding ``length`` mm up a wall from (0, y_end), the base ``lag_mm`` (from,
    to) ahead of it: distance along the wall, base x, true r and phi per pause."""
    a = math.radians(angle_deg)
    along = np.linspace(0.0, length, n)
    xc, yc = along * math.cos(a), y_end + along * math.sin(a)
    base_x = xc + np.linspace(*lag_mm, n)
    return along, base_x, np.hypot(base_x - xc, yc), np.degrees(np.arctan2(base_x - xc, yc))


def test_wall_from_a_slide_where_the_fused_estimate_lags():
    # A slide up a wall at 78 deg: past the stuck start the fusion drops GM (P = 0) and its
    # fused r trails the truth by up to 6 mm (a mean over pauses of a bias that grows each
    # pause), while MF scatters 0.3 mm about it. From MF the angle comes within 0.5 deg
    # (the largest error over 20 noise seeds is 0.14 deg); from r_hat it is 2.9 deg off.
    n = 30
    along, base_x, r, phi = _slide(78.0, 40.0, n, 50.0, (2.0, 15.0))
    stuck = along < 5.0
    p_good = np.where(stuck, 0.99, 0.0)
    r_hat = np.where(stuck, r, r - 6.0 * along / along[-1])
    r_mf = r + 0.3 * np.random.default_rng(7).standard_normal(n)
    cols = _estimates_table(r_hat, r_mf, p_good, np.zeros(n), phi, base_x)
    angle = fit_model("line", surfels_from_columns(cols)).params["angle_deg"]
    assert abs(angle - 78.0) < 0.5
    lagging = fit_model("line", surfels_from_columns({k: v for k, v in cols.items()
                                                      if k != "p_gm_good"}))
    assert abs(lagging.params["angle_deg"] - 78.0) > 2.0


def _slide_up_a_71_deg_wall(rng, sigma_mf):
    """A slide at phi ~4 deg from MF alone, its r off by 10 mm (sd) along the whisker."""
    n = 25
    along, base_x, r, phi = _slide(71.0, 35.0, n, 55.0, (0.5, 6.0))
    r_mf = r + 10.0 * rng.standard_normal(n)
    p_good = np.where(along < 3.0, 0.99, 0.0)
    return _estimates_table(r, r_mf, p_good, np.zeros(n), phi, base_x, sigma_mf)


def test_mf_scatter_along_the_whisker_tilts_a_steep_wall_less_with_its_sigma():
    # Points scattered along the whisker, 19 deg from the wall, tilt an orthogonal fit
    # toward the whisker. Scaled by the scatter across the wall (sigma_MF = 10 mm) the mean
    # tilt over 20 noise seeds is 3.2 deg; as points as good as fused ones 5.4 deg (the
    # chords between the scattered points still tilt it). Margins: 0.3 and 1.4 deg.
    def mean_tilt(sigma_mf):
        return np.mean([fit_model("line", surfels_from_columns(_slide_up_a_71_deg_wall(
            np.random.default_rng(seed), sigma_mf))).params["angle_deg"] - 71.0
                        for seed in range(20)])

    assert mean_tilt(10.0) < 3.5
    assert mean_tilt(0.0) > 4.0


def test_pose_moves_a_table_into_the_common_frame():
    pose = Pose(10.0, -5.0, 90.0)
    assert np.allclose(pose.apply(np.array([[1.0, 2.0]])), [[8.0, -4.0]])
    assert np.allclose(pose.rotate(np.array([[1.0, 0.0]])), [[0.0, 1.0]])


def _write_wall(path, rng=None):
    rng = rng or np.random.default_rng(7)
    s = np.linspace(0.0, 50.0, 30)
    a = math.radians(80.0)
    x, y = _noisy(s * math.cos(a), 40.0 + s * math.sin(a), rng)
    write_csv(path, _table(x, y, np.linspace(-30.0, -20.0, 30)))


def test_percept_command_writes_strict_json(tmp_path, capsys):
    c = tmp_path / "c.csv"
    _write_wall(c)
    out, png = tmp_path / "p.json", tmp_path / "p.png"
    assert main(["percept", "--contacts", str(c), "--out", str(out), "--plot", str(png)]) == 0

    def refuse(name):
        raise ValueError(f"non-strict JSON constant {name}")

    doc = json.loads(out.read_text(), parse_constant=refuse)
    assert doc["model"] == "line" and doc["object"] == "wall"
    assert doc["params"]["angle_deg"] == pytest.approx(80.0, abs=0.5)  # as the fit test
    lo, hi = doc["intervals_95"]["angle_deg"]
    assert lo < doc["params"]["angle_deg"] < hi
    assert doc["runner_up"] in ("circle", "corner", "none") and doc["evidence_ratio"] > 1.0
    assert doc["inputs"][0]["contacts"] == str(c) and len(doc["inputs"][0]["sha256"]) == 64
    assert doc["camwhisker"] and doc["command"].startswith("camwhisker percept")
    assert png.read_bytes()[:4] == b"\x89PNG"
    # A steeper run over the wall: the stage turned so that it rises at 83 deg.
    assert doc["next_run_angle_deg"] == pytest.approx(80.0 - 83.0, abs=0.5)
    printed = capsys.readouterr().out
    assert "wall (line) from 30 contacts" in printed
    assert f"--pose X0,Y0,{doc['next_run_angle_deg']:.1f}" in printed


@pytest.mark.parametrize("content, message", [
    ("", "empty file"),
    ("t_s,x_mm,phi_deg,x_hat_mm,r_hat_mm\n", "no rows"),
    ("t_s,x_mm,phi_deg,r_hat_mm\n0,0,0,1\n", "missing column x_hat_mm"),
    ("t_s,x_mm,phi_deg,x_hat_mm,r_hat_mm\n0,0,zero,1,1\n", "not a number"),
])
def test_bad_contact_tables_are_named_and_nothing_is_written(tmp_path, capsys, content, message):
    c = tmp_path / "c.csv"
    c.write_text(content)
    out = tmp_path / "p.json"
    assert main(["percept", "--contacts", str(c), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("camwhisker percept: error: ") and str(c) in err and message in err
    assert not out.exists()


def test_bad_pose_is_refused(tmp_path, capsys):
    c = tmp_path / "c.csv"
    _write_wall(c)
    assert main(["percept", "--contacts", str(c), "--pose", "1,2", "--out",
                 str(tmp_path / "p.json")]) == 2
    assert "X0,Y0,DEG" in capsys.readouterr().err


@pytest.mark.parametrize(("args", "message"), [
    (["--seeds", "5-2"], "the last seed is before the first"),
    (["--seeds", "0-1", "--calib-pegs", "1"], "two or more pegs"),
    (["--noise", "0.05"], "expected PHI_DEG,DZ_MM"),
    (["--noise", "0,0.02"], "both must be positive and finite"),
    (["--noise", "nan,0.02"], "both must be positive and finite"),
])
def test_percept_bench_refuses_bad_arguments(tmp_path, capsys, args, message):
    out = tmp_path / "r.json"
    assert main(["dev", "percept-bench", *args, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("camwhisker dev percept-bench: error: ") and message in err
    assert not out.exists()


def test_share_interval_is_wilsons():
    from camwhisker.bench.percepts import share_interval

    # Wilson's score interval in closed form (no continuity correction), z of 95 %; the
    # campaign's 171/180 walls and the ends, where a Wald interval would collapse to a point.
    z = 1.959963984540054
    for k, n in ((171, 180), (163, 179), (0, 60), (180, 180)):
        p, c = k / n, 1 + z * z / n
        mid = (p + z * z / (2 * n)) / c
        half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / c
        lo, hi = share_interval(k, n)
        assert lo == pytest.approx(mid - half, abs=1e-9)
        assert hi == pytest.approx(mid + half, abs=1e-9)
    # 95 % lies within 171/180's interval and above 163/179's.
    assert share_interval(171, 180)[0] < 0.95 < share_interval(171, 180)[1]
    assert share_interval(163, 179)[1] < 0.95
    assert all(math.isnan(v) for v in share_interval(0, 0))


def test_simulated_sweeps_of_each_object():
    from camwhisker.bench.percepts import run_campaign, summarise

    # Tuning seeds 0-3 and 9: wall, cylinder, corner, wall, nothing (seed % 10 picks the kind).
    rows = run_campaign([0, 1, 2, 3, 9])
    assert [r["kind"] for r in rows] == ["wall", "cylinder", "corner", "wall", "none"]
    assert all(r["correct"] for r in rows)
    s = summarise(rows)
    # These seeds' errors (looked at while tuning), with room for a change in the
    # simulator's numerics: radius 0.10 mm, centre 0.01 mm, apex 0.11 mm, wall angles 0.06
    # and 0.50 deg, distances 0.03 and 0.37 mm (3.6 deg and 4.6 mm while the fusion averaged
    # seed 3's slide back into its stuck start: contact.slip).
    assert s["radius_err_mm"]["max"] < 1.0
    assert s["center_err_mm"]["max"] < 3.5
    assert s["apex_err_mm"]["max"] < 1.5
    assert s["angle_err_deg"]["max"] < 1.5
    assert s["distance_err_mm"]["max"] < 1.5
    # Where an interval is within the target the error is too: the cylinder's radius and centre
    # and the corner's apex claim 0.15, 0.42 and 1.33 mm; the walls, calibrated on the paper's
    # 8 pegs, claim only 2.1 and 2.4 deg, so no wall claims 1 deg.
    for key in ("radius_err_mm", "center_err_mm", "apex_err_mm"):
        assert s[key]["claimed"] == s[key]["claimed_within"] == 1
    assert s["angle_err_deg"]["claimed"] == 0
    assert min(r["claimed"]["angle_err_deg"] for r in rows if r["kind"] == "wall") > 1.5


def test_a_turned_run_sees_the_same_wall():
    from camwhisker.sim.mechanics.objects import draw_sweep, turned_wall_run

    # The turned run's face, put back in the common frame by its pose, is the wall: its lower
    # end on the wall's, its top on the wall's line (to rounding).
    sweep = draw_sweep("wall", np.random.default_rng(7))
    run = turned_wall_run(sweep.runs[0], -10.0)
    box = run.scene
    assert box.face_angle_deg == pytest.approx(sweep.truth["angle_deg"] + 10.0, abs=1e-9)
    ends = Pose(*run.pose).apply(np.array([box.point_at(0.0), box.point_at(box.face_length_mm)]))
    assert ends[0] == pytest.approx([0.0, sweep.truth["end_y_mm"]], abs=1e-9)
    a = math.radians(sweep.truth["angle_deg"])
    across = (ends[1, 0] * math.sin(a) - (ends[1, 1] - sweep.truth["end_y_mm"]) * math.cos(a))
    assert abs(across) < 1e-9


def test_the_second_run_turns_the_fitted_line_steep():
    from camwhisker.percept.percepts import BLIND_TURN_DEG, RISE_DEG, steep_turn_deg

    # A wall at 75 deg fitted to 0.07 deg (test_line_fit_recovers_the_wall): turned by
    # 75 - RISE_DEG within 0.5 deg. Two contacts fit no line: the blind turn.
    turn = steep_turn_deg(perceive(_wall(np.random.default_rng(1))))
    assert turn == pytest.approx(75.0 - RISE_DEG, abs=0.5)
    two = surfels_from_columns(_table([0.0, 1.0], [40.0, 44.0]))
    assert steep_turn_deg(perceive(two)) == BLIND_TURN_DEG


def test_corner_whose_first_slide_comes_from_scattered_mf():
    from camwhisker.bench.percepts import run_campaign

    # Sweeps 1078 and 1152 of the held-out campaign: face 1 slides at phi ~4 deg, where MF
    # scatters 12 mm along the whisker, and the apex candidates' angular groups missed that
    # face: the corner fitted 52 and 62 mm from the apex. Started from the lines fitted to
    # each run it comes within 0.06 and 0.04 mm; the target is 2 mm.
    rows = run_campaign([1078, 1152])
    assert [r["chosen"] for r in rows] == ["corner", "corner"]
    assert max(r["apex_err_mm"] for r in rows) < 2.0


def test_nothing_swept_at_a_quiet_front_ends_noise_is_no_object():
    from camwhisker.bench.percepts import run_campaign
    from camwhisker.sim.mechanics.experiment import NoiseModel

    # Tuning seeds 9 and 19 (nothing touched) at the noise the front end reaches on hand-made
    # builds, calibrated on 15 pegs: while MF's floor fell to 0 deg there, both were walls.
    rows = run_campaign([9, 19], pegs=15, noise=NoiseModel(phi_deg=0.02, dz_mm=0.005))
    assert [r["chosen"] for r in rows] == ["none", "none"]


def test_after_a_slip_under_mfs_floor_gm_alone_is_no_contact_point():
    from camwhisker.bench.contact import _log, calibrate_simulated
    from camwhisker.bench.percepts import CALIB_SEED, PROTOCOL, run_campaign
    from camwhisker.contact.pipeline import contact_rows
    from camwhisker.sim.mechanics.experiment import FRONT_END_NOISE, peg_radii, simulate_run
    from camwhisker.sim.mechanics.objects import draw_sweep

    # Tuning sweep 126: the wall's contact sticks at its lower end until phi 2.4 deg, then
    # slips up the face with phi steady under MF's floor (2.5 deg). GM alone read the slide
    # as a contact running out from 69 to 147 mm (truth 59-89 mm), and the wall came out
    # 19 deg off with a +-0.6 deg interval. From the slip on, GM without MF is no estimate.
    rng = np.random.default_rng(126)
    run_spec = draw_sweep("wall", rng).runs[0]
    run = simulate_run("run0", "slide-box", run_spec.scene, rng, protocol=PROTOCOL,
                       noise=FRONT_END_NOISE, travel_sign=1.0)
    calib = calibrate_simulated(CALIB_SEED, noise=FRONT_END_NOISE, radii_mm=peg_radii(15))
    cols, _ = contact_rows(run.signals, _log(run, False), calib, None, mode="pause")
    slip = np.array(["slip" in d.split(";") for d in cols["doubt"]])
    first = int(np.argmax(slip))
    assert slip.any() and np.isnan(cols["p_gm_good"][first:]).all()  # no MF in reach
    assert not np.isfinite(cols["r_hat_mm"][first:]).any()
    # The stuck contact before it keeps GM's estimate: 58.27 mm against 58.29 true at its
    # last pause (1 mm: a few of GM's 0.6 mm spreads).
    before = cols["r_hat_mm"][:first][np.isfinite(cols["r_hat_mm"][:first])]
    assert before.size and abs(before[-1] - 58.29) < 1.0
    # That run alone leaves too few contacts for a shape. The campaign's second run, turned
    # blind for want of a line (the face at 82 deg), finds the wall 0.33 deg off.
    assert surfels_from_columns(cols).n < MIN_SURFELS
    [row] = run_campaign([126], pegs=15)
    assert row["chosen"] == "line" and row["angle_err_deg"] < 1.0
