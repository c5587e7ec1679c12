"""Whisker mechanics: closed-form beam, elastica, where they part, simulated runs."""

import math

import numpy as np
import pytest

from camwhisker.mechanics import (
    PegScene,
    WhiskerMechanics,
    beam_peg_response,
    signal_arrays,
    simulate_runs,
    sweep,
)
from camwhisker.mechanics.experiment import PAPER_C, PAPER_RIGID_RADII_MM
from camwhisker.mechanics.scenes import BoxScene, CircleScene
from camwhisker.mechanics.whisker import PHI_LINEAR_MAX_DEG

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
    from camwhisker.mechanics.whisker import solve_elastica

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


def test_circle_contact_slides_box_corner_does_not():
    circ = sweep(CircleScene(0.0, 80.0, 35.0), MECH, np.arange(-34.0, 0.0))
    box = sweep(BoxScene(75.0), MECH, np.arange(1.0, 30.0))
    moved_c = np.hypot(np.diff(circ.contact_x_mm[[0, -1]]), np.diff(circ.contact_y_mm[[0, -1]]))
    assert moved_c[0] > 10.0 and circ.slipping[-1]
    assert np.nanmax(np.abs(box.contact_x_mm)) < 1e-6 and not box.slipping.any()


def test_runs_have_clock_offset_and_tables():
    run = simulate_runs("compliant", 3)[0]
    assert 3.0 <= abs(run.offset_s) <= 8.0
    assert set(run.signals) >= {"frame", "t_s", "dz_mm", "phi_deg", "theta_deg", "ok"}
    assert "r_mm" not in run.stage
    assert np.all(np.diff(run.stage["t_s"]) > 0)
    # The noise is the paper's: phi residual RMS near 0.22 deg in contact.
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
