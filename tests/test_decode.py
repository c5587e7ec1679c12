"""MJPG decoded by libjpeg-turbo: the same pixels in batch, replay and live."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from camwhisker.io.sources import JPEG_DECODER, VideoSource, decode_jpeg, open_source
from camwhisker.live.capture import DRIVER_CLOCK, READ_CLOCK
from camwhisker.live.grabber import Grabber
from camwhisker.live.record import (
    DecodeKeepingJpeg,
    MjpgRoundTrip,
    SessionRecorder,
    decode_only,
    recorded_jpegs,
)

SAMPLE = Path(__file__).resolve().parents[1] / "sample_frames" / "nominal_mjpg.avi"


@pytest.fixture(scope="module")
def sample_frames():
    return list(VideoSource(SAMPLE))


def test_an_mjpg_file_is_decoded_as_the_live_loop_decodes_its_bytes(sample_frames):
    src = VideoSource(SAMPLE)
    assert src.decoder == JPEG_DECODER
    jpegs = list(recorded_jpegs(SAMPLE))
    assert len(jpegs) == len(sample_frames) == 12
    raw = np.frombuffer(jpegs[3], np.uint8)  # a camera's raw MJPG: a 1-D uint8 array
    # Bit for bit (tolerance 0): one decoder for the file and for every live path.
    for image in (decode_jpeg(jpegs[3]), MjpgRoundTrip()(raw)[0], decode_only(raw)[0],
                  DecodeKeepingJpeg()(raw)[0]):  # fmt: skip
        assert np.array_equal(image, sample_frames[3].image)
    assert MjpgRoundTrip()(raw)[1] == jpegs[3]  # the camera's bytes are kept as sent


def test_libjpeg_turbo_differs_from_ffmpeg_only_by_chroma_upsampling(sample_frames):
    cap = cv2.VideoCapture(str(SAMPLE))
    for frame in sample_frames[:4]:
        ok, ffmpeg = cap.read()
        diff = np.abs(frame.image.astype(int) - ffmpeg)
        # Measured 27-32 DN max, 0.81-0.84 DN mean on this clip: the decoders' chroma
        # upsampling differs at colour edges (~30 DN); 40 / 1.5 leave room for FFmpeg builds.
        assert diff.max() <= 40 and diff.mean() <= 1.5
    cap.release()


def test_look_ahead_and_one_thread_give_the_same_frames_and_stop_cleanly(sample_frames):
    one = list(VideoSource(SAMPLE, decode_threads=1))
    assert all(np.array_equal(a.image, b.image) for a, b in zip(one, sample_frames, strict=True))
    before = threading.active_count()
    it = iter(VideoSource(SAMPLE))
    next(it), next(it)
    it.close()  # a reader that stops early (max frames, a live stop)
    assert threading.active_count() == before  # the decoding thread is gone


def test_a_corrupt_mjpg_frame_is_a_gap_and_reading_goes_on(tmp_path):
    jpegs = list(recorded_jpegs(SAMPLE))[:6]
    rec = SessionRecorder(tmp_path / "s.avi", 30.0)
    for k, data in enumerate(jpegs):
        data = data[: len(data) // 2] if k == 2 else data  # frame 2 cut short
        rec.write(k, k, k / 30.0, data, (720, 1280, 3))
    rec.close()
    src = VideoSource(tmp_path / "s.avi")
    frames = list(src)
    assert [f.index for f in frames] == list(range(6))
    assert [f.index for f in frames if f.image is None] == src.lost_frames == [2]
    assert frames[2].event == "gap" and src.frames_read == 5
    assert np.array_equal(frames[3].image, decode_jpeg(jpegs[3]))
    assert "frames 2 of 6 could not be decoded" in src.problem
    assert "damaged" not in src.problem  # every MJPG frame is a key frame
    # The session replays the same: its lost frame a gap, the rest its recorded pixels.
    session = list(open_source(tmp_path / "s.avi"))
    assert [f.event for f in session] == ["", "", "gap", "", "", ""]


def test_bytes_that_are_not_a_jpeg_are_refused_not_half_decoded():
    with pytest.raises(ValueError):
        decode_only(np.frombuffer(b"\xff\xd8" + bytes(500), np.uint8))


def test_other_codecs_keep_opencv():
    mp4 = SAMPLE.with_name("nominal.mp4")
    assert VideoSource(mp4).decoder == "OpenCV (FFmpeg)"


class StampedCapture:
    """Three tiny frames, each with a driver time ``offset_s`` from the read's monotonic
    time (a V4L2 buffer's: a few ms before; another clock's: far off), then the end."""

    def __init__(self, offset_s: float):
        self.offset_s, self.n, self.stamps = offset_s, 0, []

    @property
    def ended(self):
        return self.n >= 3

    def read(self):
        if self.n >= 3:
            return False, None
        self.n += 1
        self.stamps.append(time.monotonic() + self.offset_s)
        return True, np.zeros((4, 4, 3), np.uint8)

    def capture_time_s(self):
        return self.stamps[-1]


def _grab_all(capture) -> tuple[list, Grabber]:
    g = Grabber(capture, "every").start()
    items = []
    while (item := g.get(5.0)) is not None:
        items.append(item)
    g.stop()
    return items, g


def test_frames_carry_the_drivers_buffer_time_where_it_is_on_the_monotonic_clock():
    cap = StampedCapture(-0.004)
    items, g = _grab_all(cap)
    assert [i.t_s for i in items] == cap.stamps  # the driver's times, exactly
    assert g.stats.clock == DRIVER_CLOCK and g.stats.driver_times == 3
    far = StampedCapture(-1e6)  # e.g. a driver on the wall clock, or a file's position
    tic = time.monotonic()
    items, g = _grab_all(far)
    assert g.stats.clock == READ_CLOCK and g.stats.driver_times == 0
    # the read's own time: after the test's clock reading, within the 5 s get timeout
    assert all(tic <= i.t_s <= tic + 5.0 for i in items)
