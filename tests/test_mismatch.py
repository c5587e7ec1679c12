"""The mismatch check (camwhisker.vision.mismatch) on rendered rest frames.

| check | expectation | reason |
|---|---|---|
| nominal renders (nominal, distortion scenes, 3 seeds) | no warning | the issue's target |
| fx +3 % or z_i +0.6 mm, nominal file | warns, names fx or z_i | each moves phi(20 deg) ~0.6 deg |
| mosaic hard, builds 0-4, true file | <= 3 of 5 warn (blind floor: 5) | the floor grows with blur |
| the same with fx +3 % | warns on all 5 | the blur does not hide a wrong file |
| stream | one RestRecord per rest reference | the sidecar's record |
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from camwhisker.sensor.file import Sensor
from camwhisker.sensor.model import PlateModel, geometry_vector
from camwhisker.sensor.plate import Pose
from camwhisker.sim.render.artefacts import apply_artefacts, illumination_field, jpeg_roundtrip
from camwhisker.sim.render.builds import draw_build
from camwhisker.sim.render.render import SceneRenderer
from camwhisker.sim.render.scenarios import make_scenario
from camwhisker.sim.render.video import render_frames
from camwhisker.vision import FrontEnd, mismatch
from camwhisker.vision.mismatch import PHI_ERROR_WARN_DEG, check_mismatch, phi_error_deg
from camwhisker.vision.stream import Frame, RestRecord, stream


def _rest_frame(sensor: Sensor, scene: str, seed: int) -> np.ndarray:
    """A rest frame of ``sensor`` under the scene's webcam artefacts."""
    art = make_scenario(scene, 4, seed).artefacts
    renderer = SceneRenderer(sensor)
    rng = np.random.default_rng(seed)
    frame = apply_artefacts(renderer.geometry(Pose()), 0.0, art, rng,
                            illumination_field(renderer.shape, art))  # fmt: skip
    return jpeg_roundtrip(frame, art.jpeg_quality) if art.jpeg_quality else frame


def _check(build: Sensor, scene: str, seed: int, nominal: Sensor):
    fe = FrontEnd(nominal)
    fe.start(_rest_frame(build, scene, seed))
    return check_mismatch(fe.rest, fe.model)


@pytest.mark.parametrize(("scene", "seed"), [("nominal", 11), ("nominal", 12), ("distortion", 13)])
def test_no_warning_on_nominal_renders(scene, seed):
    sc = make_scenario(scene, 4, seed)
    sensor = Sensor().replace(**sc.sensor_changes) if sc.sensor_changes else Sensor()
    check = _check(sensor, scene, seed, sensor)
    assert not check.warned, check
    assert check.message == ""


@pytest.mark.parametrize(
    ("changes", "suspect"),
    [
        ({"camera": {"fx_px": Sensor().camera.fx_px * 1.03,
                     "fy_px": Sensor().camera.fy_px * 1.03}}, ("camera.f", "plate.z_i")),
        ({"plate": {"z_i_mm": Sensor().plate.z_i_mm + 0.6}}, ("camera.f", "plate.z_i")),
    ],
)  # fmt: skip
def test_warns_on_a_deviated_build(changes, suspect):
    nominal = Sensor()
    build = nominal.replace(**changes)
    deviation = geometry_vector(build) - geometry_vector(nominal)
    assert phi_error_deg(PlateModel(nominal), deviation) > PHI_ERROR_WARN_DEG
    check = _check(build, "nominal", 21, nominal)
    assert check.warned, check
    assert check.suspects[0].startswith(suspect), check.suspects
    assert "calibrate-sensor" in check.message
    assert check.phi_error_deg > PHI_ERROR_WARN_DEG


def _build_rest_frame(seed: int):
    """A hand build's rest frame in another camera's look (mosaic pipeline, hard look)."""
    build = draw_build(seed, pipeline="mosaic", look="hard")
    sc = build.scenario(make_scenario("nominal", 4, seed))
    assert sc.track.phi_deg[0] == 0 and sc.track.dz_mm[0] == 0  # the first frame at rest
    frame = next(render_frames(sc, build.sensor, seed, appearance=build.appearance))
    q = sc.artefacts.jpeg_quality
    return build.sensor, (jpeg_roundtrip(frame, q) if q else frame)


def test_the_noise_floor_grows_with_the_blur(monkeypatch):
    warned = {"true": 0, "fx +3 %": 0, "true, blind floor": 0}
    for seed in range(5):  # tuning builds
        true, frame = _build_rest_frame(seed)
        cam = true.camera
        wrong = true.replace(camera={"fx_px": cam.fx_px * 1.03, "fy_px": cam.fy_px * 1.03})
        for name, sensor in (("true", true), ("fx +3 %", wrong)):
            fe = FrontEnd(sensor)
            fe.start(frame)
            warned[name] += check_mismatch(fe.rest, fe.model).warned
            assert fe.rest.share_blur_px > 2.5  # the look's blur: the floor is above 0.5 px
        with monkeypatch.context() as m:
            m.setattr(mismatch, "BIAS_PER_BLUR", 0.0)
            fe = FrontEnd(true)
            fe.start(frame)
            warned["true, blind floor"] += check_mismatch(fe.rest, fe.model).warned
    # A wrong file warns on every build, the true one on fewer than the blind floor's 5
    # (3 measured: this look's detection bias still exceeds the floor on some builds).
    assert warned["fx +3 %"] == 5 and warned["true, blind floor"] == 5
    assert warned["true"] <= 3


def test_stream_records_each_rest_reference():
    sensor = Sensor()
    image = _rest_frame(sensor, "nominal", 31)
    frames = [Frame(0, 0.0, image), Frame(1, 1 / 30, image, "rezero")]
    log: list = []
    rows = list(stream(frames, sensor, rest_log=log))
    assert len(rows) == 2
    assert [type(r) for r in log] == [RestRecord, RestRecord]
    assert [r.frame for r in log] == [0, 1]
    record = log[0].as_dict()
    assert record["mismatch_check"]["warned"] is False
    assert math.isfinite(record["mismatch_check"]["residual_rms_px"])
