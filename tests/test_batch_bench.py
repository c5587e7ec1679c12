"""The batch-against-read benchmark's video: the source looped forward and back, MJPG."""

import cv2
import numpy as np

from camwhisker.bench.batch_read import make_video


def test_the_loop_plays_forward_back_and_forward(tmp_path):
    src = tmp_path / "src.avi"
    levels = [20, 70, 120, 170, 220]
    writer = cv2.VideoWriter(str(src), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (64, 48))
    for v in levels:
        writer.write(np.full((48, 64, 3), v, np.uint8))
    writer.release()
    out = tmp_path / "loop.avi"
    assert make_video(src, out, frames=12) == 12
    cap = cv2.VideoCapture(str(out))
    means = []
    while (got := cap.read())[0]:
        means.append(float(got[1].mean()))
    want = (levels + levels[::-1] + levels)[:12]
    assert len(means) == 12
    # A flat grey through YUV and JPEG twice comes back a few DN off (-2.3 here): within
    # 5 DN, each frame is its level's and no other's (levels 50 DN apart).
    assert np.abs(np.array(means) - want).max() < 5.0
