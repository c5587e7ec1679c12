"""Accuracy of the front end on rendered frames, against the renderer's truth.

Seeds here are not the ones the front end was tuned on (101-103). Frames go
through the webcam artefacts and an in-memory JPEG round trip at the
scenario's quality, as an MJPG video would. Few frames keep the module under
a minute; the benchmark (camwhisker dev vision-bench) runs more.

| check | tolerance | reason |
|---|---|---|
| nominal phi RMSE | 0.05 deg | issue #3 target; 0.05 deg is 0.47 px of tip motion |
| nominal dz RMSE | 0.02 mm | issue #3 target; ~0.1 px of corner motion |
| nominal theta MAE (phi >= 2 deg) | 1 deg | issue #3 target |
| distortion | 1.5 x nominal | issue #3 target |
| hard phi / dz RMSE | 0.15 deg / 0.05 mm | issue #3 target (noise 5 DN, blur 2.6 px) |
| hard rows ok | >= 95% | issue #3 target |
| zero motion (identical frames) | 1e-5 deg, mm; 1e-4 px | float32 rounding only (~1e-5 px) |
| rest frames with fresh noise | 0.02 deg, 0.005 mm | ~5 sigma of the rest noise |
| tip's rim placed at the reported pose | RIM_REFIT_MM, RIM_REFIT_RAD | the tracker's own rule |
| jump with 3 corners in view: fit | 0.2 deg, 0.05 mm | 3 corners pin dz and shift loosely |
| phi 32 deg, blur 1.4 px: mean error | 0.025 deg | issue: 0.04 over 30 deg; held offsets -0.048 |
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from camwhisker.sensor.file import Sensor
from camwhisker.sensor.model import TIP
from camwhisker.sim.render.artefacts import jpeg_roundtrip
from camwhisker.sim.render.scenarios import PoseTrack, make_scenario, wrap_deg
from camwhisker.sim.render.video import render_frames
from camwhisker.vision import FeaturesNotFound, FrontEnd, FrontEndOptions
from camwhisker.vision.stream import track
from camwhisker.vision.tracker import RIM_REFIT_MM, RIM_REFIT_RAD


def _render(name, n, seed):
    sc = make_scenario(name, n, seed)
    sensor = Sensor().replace(**sc.sensor_changes) if sc.sensor_changes else Sensor()
    q = sc.artefacts.jpeg_quality
    frames = [jpeg_roundtrip(f, q) if q else f for f in render_frames(sc, Sensor(), seed)]
    return sc, sensor, frames


def _errors(sc, results):
    t = sc.track
    phi = np.array([r.phi_deg for r in results])
    dz = np.array([r.dz_mm for r in results])
    theta = np.array([r.model[2] for r in results])
    ok = np.array([r.ok for r in results])
    e_phi = phi - t.phi_deg
    e_dz = dz - t.dz_mm
    big = ok & (t.phi_deg >= 2.0)
    e_theta = np.abs(wrap_deg(theta[big] - t.theta_deg[big]))
    rms = lambda e: float(np.sqrt(np.mean(e[ok] ** 2)))  # noqa: E731
    return rms(e_phi), rms(e_dz), float(e_theta.mean()), float(ok.mean())


@pytest.fixture(scope="module")
def nominal():
    sc, sensor, frames = _render("nominal", 16, 901)
    return sc, sensor, frames, list(track(frames, sensor))


@pytest.fixture(scope="module")
def distortion():
    sc, sensor, frames = _render("distortion", 12, 903)
    return sc, list(track(frames, sensor))


@pytest.fixture(scope="module")
def hard():
    sc, sensor, frames = _render("hard", 16, 902)
    return sc, list(track(frames, sensor))


def test_nominal_accuracy(nominal):
    sc, _, _, results = nominal
    phi_rmse, dz_rmse, theta_mae, ok = _errors(sc, results)
    assert ok == 1.0
    assert phi_rmse <= 0.05
    assert dz_rmse <= 0.02
    assert theta_mae <= 1.0


def test_distortion_within_one_and_a_half_nominal(distortion):
    # Held against 1.5x the nominal targets (0.05 deg, 0.02 mm, 1 deg): on 16-frame
    # clips the ratio of two measured RMSEs swings by more than 1.5x from seed to
    # seed, so the ratio itself is measured by the benchmark on 150 frames
    # (camwhisker dev vision-bench --frames 150; BENCHMARKS.md).
    sc, results = distortion
    phi_rmse, dz_rmse, theta_mae, ok = _errors(sc, results)
    assert ok == 1.0
    assert phi_rmse <= 1.5 * 0.05
    assert dz_rmse <= 1.5 * 0.02
    assert theta_mae <= 1.5 * 1.0


def test_hard_accuracy(hard):
    sc, results = hard
    phi_rmse, dz_rmse, _, ok = _errors(sc, results)
    assert ok >= 0.95
    assert phi_rmse <= 0.15
    assert dz_rmse <= 0.05


def test_paper_mode_reported_beside_model(nominal):
    sc, sensor, frames, results = nominal
    paper = list(track(frames, sensor, FrontEndOptions(mode="paper")))
    # Same frames, same points: the model's numbers ride along in paper mode.
    np.testing.assert_allclose([r.model[1] for r in paper], [r.model[1] for r in results],
                               atol=1e-12, equal_nan=True)  # fmt: skip
    phi_paper = np.array([r.phi_deg for r in paper])
    ok = np.array([r.ok for r in paper])
    # Eq. (6) reads the half-angle field of view, so phi comes out ~half: far off.
    big = ok & (sc.track.phi_deg > 10)
    assert big.sum() >= 3
    ratio = np.tan(np.radians(phi_paper[big])) / np.tan(np.radians(sc.track.phi_deg[big]))
    assert np.all((ratio > 0.4) & (ratio < 0.6))


def test_theta_empty_at_rest_and_defined_when_tilted(nominal):
    sc, _, _, results = nominal
    for r, phi in zip(results, sc.track.phi_deg, strict=True):
        if phi == 0.0:
            assert math.isnan(r.theta_deg)
        elif phi > 2.0 and r.ok:
            assert math.isfinite(r.theta_deg)


def test_zero_motion_gives_zero(nominal):
    _, sensor, frames, _ = nominal
    fe = FrontEnd(sensor)
    fe.start(frames[0])
    r = fe.update(frames[0].copy())
    assert r.ok
    assert abs(r.dz_mm) < 1e-5 and abs(r.phi_deg) < 1e-5
    assert abs(r.sx_mm) < 1e-5 and abs(r.sy_mm) < 1e-5
    np.testing.assert_allclose(r.points_uv, fe.rest.uv, atol=1e-4)


def test_rest_frames_with_fresh_noise_stay_near_zero(nominal):
    sc, _, _, results = nominal
    rest = np.flatnonzero(sc.track.phi_deg == 0)[1:]  # the rest frames after the first
    assert len(rest) >= 1
    for i in rest:
        assert abs(results[i].phi_deg) < 0.02
        assert abs(results[i].dz_mm) < 0.005


def test_input_frame_is_not_modified(nominal):
    _, sensor, frames, _ = nominal
    a, b = frames[0].copy(), frames[5].copy()
    fe = FrontEnd(sensor)
    fe.start(a)
    fe.update(b)
    np.testing.assert_array_equal(a, frames[0])
    np.testing.assert_array_equal(b, frames[5])


def test_hidden_tip_flags_the_row_and_tracking_recovers(nominal):
    sc, sensor, frames, results = nominal
    i = 6
    hidden = frames[i].copy()
    tip = results[i].points_uv[TIP]
    cu, cv_ = int(round(tip[0])), int(round(tip[1]))
    hidden[cv_ - 60 : cv_ + 60, cu - 60 : cu + 60] = (226, 226, 226)  # cloth over the tip
    seq = frames[: i] + [hidden] + frames[i + 1 :]
    again = list(track(seq, sensor))
    assert not again[i].ok and math.isnan(again[i].phi_deg) and "tip" in again[i].reason
    for j in range(i + 1, len(seq)):
        assert again[j].ok
        assert abs(again[j].phi_deg - sc.track.phi_deg[j]) < 0.1


def test_features_not_found_names_what_is_missing(nominal):
    _, sensor, frames, _ = nominal
    blank = np.full_like(frames[0], 220)
    with pytest.raises(FeaturesNotFound) as err:
        FrontEnd(sensor).start(blank)
    assert set(err.value.missing) == {"square corners", "cross arm ends", "magnifier tip"}
    no_tip = frames[0].copy()
    cu, cv_ = 640, 360
    no_tip[cv_ - 45 : cv_ + 45, cu - 45 : cu + 45] = (45, 50, 200)  # red over the tip
    with pytest.raises(FeaturesNotFound, match="magnifier tip") as err:
        FrontEnd(sensor).start(no_tip)
    assert err.value.missing == ["magnifier tip"]


def test_wrong_frame_size_is_refused(nominal):
    _, sensor, frames, _ = nominal
    with pytest.raises(ValueError, match="sensor file says"):
        FrontEnd(sensor).start(frames[0][:700])


def test_locked_gains_track_as_well_on_a_steady_cast(nominal):
    sc, sensor, frames, results = nominal
    locked = list(track(frames, sensor, FrontEndOptions(lock_gains=True)))
    phi_rmse, dz_rmse, _, ok = _errors(sc, locked)
    # The nominal cast drifts by 2% over 20 s; over 16 frames the rest gains still fit.
    assert ok == 1.0 and phi_rmse <= 0.05 and dz_rmse <= 0.02


def test_options_are_checked():
    with pytest.raises(ValueError, match="mode"):
        FrontEndOptions(mode="fast")
    for bad in (2, 12.5, True):
        with pytest.raises(ValueError, match="lk_half_px"):
            FrontEndOptions(lk_half_px=bad)


def test_tip_is_measured_with_its_rim_at_the_reported_pose(monkeypatch):
    # A sweep at 22-30 deg (poses of the live benchmark's clip, seed 3001, frames
    # 99-118), where the tip is often first found off its prediction: its rim was
    # then placed at a tilt solved from an ellipse's centre, which the rod's body
    # pulls by up to ~4 px, and the pose solved from that measurement could lie
    # within RIM_REFIT of the fit while the rim's own pose did not. The rim's
    # shape and the rays it leaves out depend on that pose (~0.03 px of tip per
    # 1e-3 rad), so the frame's last tip measurement must have its rim placed
    # within RIM_REFIT of the pose the frame reports. Measuring it at the wrong
    # pose read these frames 0.01-0.03 deg low (phi RMSE 0.043 against 0.031 deg
    # over frames 96-123).
    track = make_scenario("nominal", 150, 3001).track
    idx = [0, *range(99, 119)]
    zero = np.zeros(len(idx))
    sweep = PoseTrack(np.arange(len(idx)) / 30.0, track.dz_mm[idx], track.phi_deg[idx],
                      track.theta_deg[idx], zero, zero)
    sc = dataclasses.replace(make_scenario("nominal", 4, 905), track=sweep)
    q = sc.artefacts.jpeg_quality
    frames = [jpeg_roundtrip(f, q) for f in render_frames(sc, Sensor(), 905)]
    placed = []
    tip_at = FrontEnd._tip_at

    def spy(self, edges, q):
        placed.append(np.array(q, float))
        return tip_at(self, edges, q)

    monkeypatch.setattr(FrontEnd, "_tip_at", spy)
    fe = FrontEnd(Sensor())
    fe.start(frames[0])
    off = []
    for frame in frames[1:]:
        placed.clear()
        r = fe.update(frame)
        assert r.ok
        d = np.abs(placed[-1] - fe.q)
        off.append((d[[0, 3, 4]].max() / RIM_REFIT_MM, d[1:3].max() / RIM_REFIT_RAD))
    assert np.max(off) <= 1.0


def test_jump_with_three_corners_in_view_measures_the_tip_and_recovers():
    # A jump from rest to 20 deg and dz 0.5 mm, in a frame where noise covers all
    # but three corners (a uniform patch would make corners of its own, which the
    # LK can lock onto): three corners cannot fix the pose, so the tip's rim is
    # placed at the tilt guessed from its dark blob rather than at the corners'
    # fit. The row is flagged for its corners, not its tip; the pose fitted to the
    # three corners and the tip is still near the truth (0.2 deg and 0.05 mm: it
    # was 0.06 deg and 0.024 mm off; three corners pin dz and the shift loosely),
    # and the next, uncovered frame is tracked to the nominal tolerance.
    n = 3
    zero = np.zeros(n)
    pose_track = PoseTrack(np.arange(n) / 30.0, np.array([0.0, 0.5, 0.5]),
                           np.array([0.0, 20.0, 20.0]), np.array([0.0, 60.0, 60.0]),
                           zero, zero)  # fmt: skip
    sc = dataclasses.replace(make_scenario("nominal", 4, 906), track=pose_track)
    q = sc.artefacts.jpeg_quality
    frames = [jpeg_roundtrip(f, q) for f in render_frames(sc, Sensor(), 906)]
    fe = FrontEnd(Sensor())
    fe.start(frames[0])
    a, b = (math.radians(20.0) * f(math.radians(60.0)) for f in (math.cos, math.sin))
    corners = fe.model.corners(np.array([0.5, a, b, 0.0, 0.0])) + fe.rest.offsets[:TIP]
    covered = frames[1].copy()
    rng = np.random.default_rng(6)
    for k, (u, v) in enumerate(np.round(corners).astype(int)):
        if k not in (0, 5, 9):
            covered[v - 20 : v + 21, u - 20 : u + 21] = rng.integers(0, 256, (41, 41, 3))
    r = fe.update(covered)
    assert not r.ok and r.n_corners == 3 and "corners" in r.reason
    assert np.isfinite(r.points_uv[TIP]).all()
    assert abs(r.model[1] - 20.0) < 0.2 and abs(r.model[0] - 0.5) < 0.05
    again = fe.update(frames[2])
    assert again.ok and again.n_corners >= 8
    assert abs(again.phi_deg - 20.0) < 0.05 and abs(again.dz_mm - 0.5) < 0.02


def test_no_phi_bias_at_large_tilt_under_blur():
    """Blur pulls each detected corner ~1 px into its feature; that offset turns and
    shrinks with the corner under tilt (the tracker moves it by the corner's affine map).
    Noise-free frames, so the mean error over 4 directions is the bias alone."""
    from camwhisker.sensor.plate import Pose
    from camwhisker.sim.render.artefacts import apply_artefacts, illumination_field
    from camwhisker.sim.render.render import SceneRenderer
    from camwhisker.sim.render.scenarios import NOMINAL_ARTEFACTS

    art = dataclasses.replace(NOMINAL_ARTEFACTS, noise_dn=0.0, cast_drift=0.0, flicker=0.0,
                              jpeg_quality=0)  # fmt: skip
    renderer = SceneRenderer(Sensor())
    light = illumination_field(renderer.shape, art)
    rng = np.random.default_rng(0)

    def image(pose):
        return apply_artefacts(renderer.geometry(pose), 0.0, art, rng, light)

    errors = []
    for theta in (20.0, 110.0, 200.0, 290.0):
        fe = FrontEnd(Sensor())
        fe.start(image(Pose()))
        for phi in np.linspace(4.0, 32.0, 8):  # a ramp: each frame near its prediction
            r = fe.update(image(Pose.from_degrees(0.3, phi, theta)))
        assert r.ok
        errors.append(r.phi_deg - 32.0)
    assert abs(np.mean(errors)) < 0.025, errors
