"""Whisker mechanics: closed-form beam, elastica, where they part, simulated runs."""

import math

import numpy as np
import pytest

from camwhisker.sim.mechanics import (
    PegScene,
    WhiskerMechanics,
    beam_peg_response,
    signal_arrays,
    simulate_runs,
    sweep,
)
from camwhisker.sim.mechanics.experiment import PAPER_C, PAPER_RIGID_RADII_MM
from camwhisker.sim.mechanics.scenes import SLIP_TOL_MM, BoxScene, CircleScene
from camwhisker.sim.mechanics.whisker import PHI_LINEAR_MAX_DEG, solve_elastica

MECH = WhiskerMechanics()


def test_beam_hand_value():
    # r = 50: a = 1 - 50 / 187.5, dx/phi = r + beta r^2 / (3a); beta = k_phi / EI0.
    a = 1.0 - 50.0 / 187.5
    beta = 0.7456 / (3000.0 * math.pi * 1.5**4 / 64.0)
    phi, _, force = beam_peg_response(MECH, 50.0, 2.0)
    assert float(phi) == pytest.approx(2.0 / (50.0 + beta * 2500.0 / (3.0 * a)), rel=1e-12)
    assert float(force) == pytest.approx(0.7456 * float(phi) / 50.0, rel=1e-12)


def test_zero_travel_gives_exactly_zero():
    s = sweep(PegScene(50.0), MECH, [-1.0, 0.0], model="elastica")
    assert np.all(s.phi_deg == 0.0) and np.all(s.dz_mm == 0.0)
    assert not s.in_contact.any()


def test_elastica_converged():
    # 64 RK4 steps vs 1024: differences far below the sensor noise (1e-4 deg, 1e-5 mm).
    from camwhisker.sim.mechanics.whisker import solve_elastica

    scene = PegScene(90.0)
    c = scene.constraint(MECH)
    a = solve_elastica(MECH, 30.0, c, scene.guess(MECH, 30.0), n_steps=64)
    b = solve_elastica(MECH, 30.0, c, a.unknowns, n_steps=1024)
    assert abs(a.phi_deg - b.phi_deg) < 1e-4
    assert abs(a.dz_mm - b.dz_mm) < 1e-5


def test_beam_and_elastica_part():
    """Below PHI_LINEAR_MAX_DEG the beam is within 0.02 deg of the elastica (a tenth of the
    paper's phi noise); by 20 deg it is off by more than 0.5 deg (>2 noise levels)."""
    xs = np.arange(0.0, 41.0, 0.5)
    worst_small, worst_large = 0.0, 0.0
    for r in (22.5, 50.0, 90.0):
        el = sweep(PegScene(r), MECH, xs, model="elastica")
        bm = sweep(PegScene(r), MECH, xs, model="beam")
        diff = np.abs(el.phi_deg - bm.phi_deg)
        small = el.phi_deg < PHI_LINEAR_MAX_DEG
        worst_small = max(worst_small, float(diff[small].max()))
        large = el.phi_deg > 20.0
        if large.any():
            worst_large = max(worst_large, float(diff[large].min()))
    assert worst_small < 0.02
    assert worst_large > 0.5


def test_ranges_like_the_paper():
    runs = simulate_runs("rigid", 5)
    phi_max = max(np.nanmax(r.truth["phi_deg"]) for r in runs)
    dz_max = max(np.nanmax(r.truth["dz_mm"]) for r in runs)
    assert 20.0 <= phi_max <= 35.0
    # "up to ~1 mm": the stiffest contact (r = 22.5 mm at phi = 30 deg) reaches a bit more.
    assert 0.8 <= dz_max <= 2.0


def test_compliant_peg_gives_way():
    rigid = sweep(PegScene(55.0), MECH, [20.0])
    soft = sweep(PegScene(55.0, k_obj_n_per_mm=6e-4), MECH, [20.0])
    assert soft.phi_deg[0] < 0.8 * rigid.phi_deg[0]
    assert soft.contact_x_mm[0] > 1.0  # the peg moved by more than a millimetre


BOX = BoxScene(0.0, 40.0, face_angle_deg=78.0, mu=0.5)
BOTTLE = CircleScene(0.0, 55.0, 45.0)


def _travel(scene, n=40):
    xs = scene.first_contact_x(MECH) + np.arange(0.0, n + 1.0)
    return xs, sweep(scene, MECH, xs)


def test_box_sticks_at_the_corner_then_slides_up_its_face():
    """Coulomb stick / slip (mu = 0.5, face at 78 deg): the corner holds while the load is
    inside the cone (|T| / N <= mu); then the contact slides up the face with the load on the
    cone's edge, phi steady (Fig. 9: 'the whisker began to slip') while r keeps growing."""
    xs, s = _travel(BOX)
    stick = s.in_contact & ~s.sliding
    slide = s.in_contact & s.sliding
    assert stick.sum() >= 8 and slide.sum() >= 15
    # Stick: the object point is the corner, to the solver's tolerance.
    assert np.max(np.hypot(s.contact_x_mm[stick], s.contact_y_mm[stick] - 40.0)) < 1e-6
    assert not s.slipping[stick].any() and s.slipping[slide].all()
    # Slip: the contact moves up the face (on it to 1e-6 mm) ...
    dx, dy = math.cos(math.radians(78.0)), math.sin(math.radians(78.0))
    off_face = np.abs(s.contact_x_mm[slide] * dy - (s.contact_y_mm[slide] - 40.0) * dx)
    assert np.max(off_face) < 1e-6
    assert np.all(np.diff(s.r_mm[slide]) > 1.5)
    # ... while phi stabilises: it changes at under 10 % of its rate while stuck
    # (it falls slightly as the lever grows), over >= 15 mm of travel.
    rate_stick = np.mean(np.diff(s.phi_deg[stick][1:]))
    rate_slide = np.abs(np.diff(s.phi_deg[slide]))
    assert rate_stick > 1.0 and np.max(rate_slide) < 0.1 * rate_stick
    assert np.all(np.diff(s.phi_deg[slide]) < 0.0)  # never grows again
    # The load sits on the cone's edge while sliding.
    for x in xs[slide][::5]:
        from camwhisker.sim.mechanics.scenes import _stick_or_slip

        i = int(np.flatnonzero(xs == x)[0])
        sol, slid = _stick_or_slip(BOX, MECH, x, (s.contact_x_mm[i - 1], s.contact_y_mm[i - 1]),
                                   BOX.slip_constraint(MECH), None)
        assert slid
        assert BOX.cone_ratio(sol.unknowns[2], *sol.contact_xy_mm) == pytest.approx(0.5, abs=1e-6)


def test_bottle_side_slides_down_tangent_to_it():
    """The whisker's side on a circle: at every step the contact lies on the circle and the
    whisker is tangent there (to the solver's 1e-7), and as the base travels on the point of
    tangency slides down the near side toward the base line, so r falls steadily."""
    xs, s = _travel(BOTTLE)
    c = s.in_contact
    assert c.sum() >= 38 and s.elastica[c].all()
    on = np.hypot(s.contact_x_mm[c], s.contact_y_mm[c] - 55.0) - 45.0
    assert np.max(np.abs(on)) < 1e-6
    for x in xs[c][::8]:
        sol = solve_elastica(MECH, x, BOTTLE.constraint(MECH), BOTTLE.guess(MECH, x))
        radius_dir = math.atan2(sol.contact_xy_mm[1] - 55.0, sol.contact_xy_mm[0])
        tangent = sol.beta_contact_rad
        assert abs(math.cos(radius_dir - tangent)) < 1e-6  # radius normal to the whisker
    assert np.all(np.diff(s.r_mm[c]) < 0.0) and np.all(np.diff(s.contact_y_mm[c]) < 0.0)
    # By phi = 30 deg the contact has slid > 20 mm down the bottle: the GM's fixed-point
    # assumption fails. The slip flag follows the truth (moved > SLIP_TOL_MM).
    at30 = int(np.flatnonzero(s.phi_deg > 30.0)[0])
    assert s.contact_y_mm[c][0] - s.contact_y_mm[at30] > 20.0
    moved = np.hypot(s.contact_x_mm - s.contact_x_mm[c][0], s.contact_y_mm - s.contact_y_mm[c][0])
    assert np.array_equal(s.slipping[c], moved[c] > SLIP_TOL_MM)


def test_bottle_swept_from_both_sides_mirrors():
    """The bottle run in -x is the +x run mirrored: the same phi and dz, the stage log and
    the contact truth at -x, the whisker leaning the other way (theta 180 deg)."""
    left, right = simulate_runs("slide-circle", 7)
    assert (left.travel_sign, right.travel_sign) == (1.0, -1.0)
    assert np.array_equal(left.steps.phi_deg, right.steps.phi_deg)
    assert np.all(np.diff(right.stage["x_mm"]) <= 0.0) and right.stage["x_mm"][0] > 45.0
    cx = right.truth["contact_x_mm"]
    assert np.nanmin(cx) > 0.0 and np.nanmax(cx) <= 45.0 + 1e-9
    theta = right.signals["theta_deg"][right.truth["phi_deg"] > 5.0]
    assert np.nanmax(np.abs(np.abs(theta) - 180.0)) < 5.0  # 0.22 deg noise at phi > 5 deg


def test_runs_have_clock_offset_and_tables():
    run = simulate_runs("compliant", 3)[0]
    assert 3.0 <= abs(run.offset_s) <= 8.0
    assert set(run.signals) >= {"frame", "t_s", "dz_mm", "phi_deg", "theta_deg", "ok"}
    assert "r_mm" not in run.stage
    assert np.all(np.diff(run.stage["t_s"]) > 0)
    # The default noise is the paper's: phi residual RMS near 0.22 deg in contact.
    t = run.truth
    sel = (t["phi_deg"] > 5.0) & run.signals["ok"].astype(bool)
    rms = np.sqrt(np.mean((run.signals["phi_deg"][sel] - t["phi_deg"][sel]) ** 2))
    assert 0.18 < rms < 0.26


def test_signal_arrays_for_renderer():
    run = simulate_runs("rigid", 3)[-1]
    a = signal_arrays(run, 60.0)
    b = signal_arrays(run, 30.0)
    assert a["t_s"].size == pytest.approx(2 * b["t_s"].size, abs=2)
    assert np.allclose(a["phi_deg"][::2][: b["t_s"].size], b["phi_deg"][: a["t_s"][::2].size])
    assert np.isnan(a["theta_deg"][0]) and a["phi_deg"][0] == 0.0


def test_eq8_mode_follows_eq8():
    run = simulate_runs("eq8", 4)[0]
    r = PAPER_RIGID_RADII_MM[0]
    steps = run.steps
    dx = steps.base_x_mm - run.info["x_first_contact_mm"]
    sel = dx > 0
    expect = PAPER_C * dx[sel] * (150.0 - r) / (r * 150.0)
    assert np.allclose(steps.phi_deg[sel], expect, rtol=1e-12)
