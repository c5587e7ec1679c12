"""The mismatch check (camwhisker.vision.mismatch) on rendered rest frames.

| check | expectation | reason |
|---|---|---|
| nominal renders (nominal, distortion scenes, 3 seeds) | no warning | the issue's target |
| fx +3 % or z_i +0.6 mm, nominal file | warns, names fx or z_i | each moves phi(20 deg) ~0.6 deg |
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
from camwhisker.sim.render.render import SceneRenderer
from camwhisker.sim.render.scenarios import make_scenario
from camwhisker.vision import FrontEnd
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
