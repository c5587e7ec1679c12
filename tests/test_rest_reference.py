"""The rest reference averaged over the frames at rest (camwhisker.vision.stream).

| check | expectation | reason |
|---|---|---|
| K rest frames then motion | K frames used (+-1) | motion ends the segment |
| 1 or 2 frames off rest amid rest | held out of the mean; the segment goes on | noise |
| REST_EXIT_FRAMES off in a row | the segment ends before the last | motion |
| rest rows' mean dz error, 5 DN, 4 seeds | RMS < 0.6 x frame 0's alone | expected ~0.3 x |
| ... the same | < half the per-frame dz noise | the issue's target |
| a stream that moves at once | 1 frame used, says so | nothing averaged over motion |
| rows held (batch) or not (live) | one row per frame, in order | the table's contract |
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from camwhisker.live.loop import LiveProcessor
from camwhisker.sensor.file import Sensor
from camwhisker.sensor.plate import Pose
from camwhisker.sim.render.artefacts import apply_artefacts, illumination_field, jpeg_roundtrip
from camwhisker.sim.render.render import SceneRenderer
from camwhisker.sim.render.scenarios import NOMINAL_ARTEFACTS
from camwhisker.vision import FrontEnd, FrontEndOptions
from camwhisker.vision.stream import (
    ONE_FRAME_WARNING,
    REST_EXIT_FRAMES,
    REST_FRAMES,
    Frame,
    stream,
)

SENSOR = Sensor()
AVERAGED = FrontEndOptions()  # the default: averaged over up to REST_FRAMES
#: The rest noise of a poor webcam: the reference's own noise matters most there.
NOISY = dataclasses.replace(NOMINAL_ARTEFACTS, noise_dn=5.0)


@pytest.fixture(scope="module")
def renderer():
    return SceneRenderer(SENSOR)


def _frames(renderer, poses, seed, art=NOMINAL_ARTEFACTS):
    """One frame per pose, each with fresh noise, as Frames at 30 fps."""
    rng = np.random.default_rng(seed)
    light = illumination_field(renderer.shape, art)
    scenes: dict = {}
    out = []
    for i, pose in enumerate(poses):
        if pose not in scenes:
            scenes[pose] = renderer.geometry(pose)
        image = apply_artefacts(scenes[pose], i / 30, art, rng, light)
        out.append(Frame(i, i / 30, jpeg_roundtrip(image, art.jpeg_quality)))
    return out


def _moving(k_rest: int, n_moving: int) -> list[Pose]:
    return [Pose()] * k_rest + [
        Pose.from_degrees(0.0, 0.5 * (j + 1), 30.0) for j in range(n_moving)
    ]


def test_rest_segment_found(renderer):
    k = 8
    frames = _frames(renderer, _moving(k, 3), seed=41)
    log: list = []
    rows = list(stream(frames, SENSOR, AVERAGED, rest_log=log))
    assert [f.index for f, _ in rows] == list(range(len(frames)))
    assert all(r.ok for _, r in rows)
    assert len(log) == 1 and abs(log[0].frames_used - k) <= 1
    assert log[0].warnings == ()
    # The moving rows are tracked with the rebuilt reference.
    assert rows[-1][1].phi_deg == pytest.approx(1.5, abs=0.1)


@pytest.mark.parametrize("n_off, used", [(1, 11), (2, 11), (REST_EXIT_FRAMES, 5)])
def test_frames_off_rest_are_held_out_until_enough_in_a_row(renderer, n_off, used):
    """Frames read off rest (here truly tilted 0.3 deg) are held out of the mean; fewer
    than REST_EXIT_FRAMES in a row do not end the segment."""
    off = Pose.from_degrees(0.0, 0.3, 30.0)
    poses = [Pose()] * 5 + [off] * n_off + [Pose()] * 6
    log: list = []
    rows = list(stream(_frames(renderer, poses, seed=45), SENSOR, AVERAGED, rest_log=log))
    assert [f.index for f, _ in rows] == list(range(len(poses)))
    assert all(r.ok for _, r in rows)
    assert len(log) == 1 and log[0].frames_used == used
    # Every off frame reads its tilt (the rest noise at this webcam: ~0.01 deg).
    assert all(abs(r.phi_deg - 0.3) < 0.03 for _, r in rows[5 : 5 + n_off])


def test_at_most_rest_frames_max(renderer):
    frames = _frames(renderer, [Pose()] * (REST_FRAMES + 3), seed=42)
    log: list = []
    rows = list(stream(frames, SENSOR, AVERAGED, rest_log=log))
    assert len(rows) == len(frames) and log[0].frames_used == REST_FRAMES


def test_averaged_reference_removes_frame_zeros_bias(renderer):
    n = 20
    averaged, alone, noise = [], [], []
    for seed in (51, 52, 53, 54):
        frames = _frames(renderer, [Pose()] * n, seed, NOISY)
        dz = np.array([r.dz_mm for _, r in stream(frames, SENSOR, AVERAGED)])
        averaged.append(dz.mean())
        fe = FrontEnd(SENSOR)
        fe.start(frames[0].image)
        dz0 = np.array([0.0] + [fe.update(f.image, f.index).dz_mm for f in frames[1:]])
        alone.append(dz0.mean())
        noise.append(dz.std(ddof=1))
    rms = lambda e: float(np.sqrt(np.mean(np.square(e))))  # noqa: E731
    assert rms(averaged) < 0.6 * rms(alone), (averaged, alone, noise)
    assert rms(averaged) < 0.5 * float(np.mean(noise)), (averaged, noise)


def test_rest_frame_alone_on_request(renderer):
    frames = _frames(renderer, [Pose()] * 3, seed=43)
    log: list = []
    rows = list(stream(frames, SENSOR, FrontEndOptions(rest_frames=1), rest_log=log))
    assert rows[0][1].dz_mm == 0.0 and log[0].frames_used == 1 and log[0].warnings == ()


@pytest.mark.parametrize("hold", [True, False])
def test_one_rest_frame_works_and_says_so(renderer, hold):
    frames = _frames(renderer, _moving(1, 4), seed=61)
    log: list = []
    rows = list(stream(frames, SENSOR, AVERAGED, rest_log=log, hold_rest=hold))
    assert [f.index for f, _ in rows] == list(range(len(frames)))
    assert all(r.ok for _, r in rows)
    assert rows[0][1].dz_mm == 0.0 and rows[0][1].phi_deg == 0.0
    assert log[0].frames_used == 1 and log[0].warnings[0] == ONE_FRAME_WARNING
    assert rows[-1][1].phi_deg == pytest.approx(2.0, abs=0.1)


def test_live_rows_come_at_once(renderer):
    frames = _frames(renderer, _moving(4, 2), seed=71)
    live = LiveProcessor(SENSOR, AVERAGED)
    rows = [live.process(f.index, f.image) for f in frames]
    assert [r.frame for r in rows] == [f.index for f in frames]
    assert all(r.ok for r in rows)


def test_rebuilt_reference_keeps_the_first_frames_points(renderer):
    """The mean image's reference takes its corners from the first frame's detection
    (nothing to fail where a mean image loses a corner) and measures the tip anew: within
    0.05 px of the first frame's (~5x the tip's rest noise at this webcam)."""
    from camwhisker.sensor.model import TIP
    from camwhisker.vision.rest import mean_image

    frames = _frames(renderer, [Pose()] * 10, seed=44)
    first = FrontEnd(SENSOR)
    first.start(frames[0].image)
    rebuilt = FrontEnd(SENSOR)
    rebuilt.start(mean_image([f.image for f in frames]), 0, first.rest.uv)
    assert np.array_equal(rebuilt.rest.uv[:TIP], first.rest.uv[:TIP])
    assert np.hypot(*(rebuilt.rest.uv[TIP] - first.rest.uv[TIP])) < 0.05
    r = rebuilt.update(frames[5].image, 5)
    assert r.ok and abs(r.dz_mm) < 0.005 and r.phi_deg < 0.02  # 5 sigma of the rest noise
