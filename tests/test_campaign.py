"""Many recordings: inputs, resuming after kill -9, failures listed, local and Dask agree."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from camwhisker.run.campaign import (
    BatchTask,
    CampaignError,
    expand_inputs,
    is_complete,
    output_path,
    run_many,
    sidecar_path,
)
from camwhisker.sensor.file import Sensor

SAMPLE = Path(__file__).resolve().parents[1] / "sample_frames" / "nominal_mjpg.avi"


@pytest.fixture()
def videos(tmp_path):
    """Three good clips (two with the same name in different folders) and four bad inputs."""
    for sub in ("a", "b", "c"):
        (tmp_path / sub).mkdir()
    good = [tmp_path / "a" / "clip.avi", tmp_path / "b" / "clip.avi", tmp_path / "c" / "other.avi"]
    for p in good:
        shutil.copy(SAMPLE, p)
    data = SAMPLE.read_bytes()
    bad = {
        "empty.avi": b"",
        "notvideo.mp4": b"this is a text file, not a video\n" * 20,
        "truncated.avi": data[: len(data) // 2],
        "corrupt.avi": data[:4096] + os.urandom(len(data) - 4096),
    }
    for name, content in bad.items():
        (tmp_path / "c" / name).write_bytes(content)
    return tmp_path, good, [tmp_path / "c" / n for n in bad]


def test_expand_inputs_files_folders_globs(videos):
    root, good, bad = videos
    found = expand_inputs([root / "a", str(root / "*" / "clip.avi"), good[2], good[0]])
    assert found == [good[0], good[1], good[2]]  # order kept, duplicates dropped
    assert len(expand_inputs([root])) == 7
    with pytest.raises(CampaignError, match="matches no file"):
        expand_inputs([str(root / "*.nothing")])
    with pytest.raises(CampaignError, match="holds no video"):
        (root / "empty_dir").mkdir()
        expand_inputs([root / "empty_dir"])


def test_outputs_do_not_collide(videos):
    root, good, _ = videos
    outs = {output_path(v, root / "out", root=root) for v in good}
    assert len(outs) == 3
    assert output_path(good[0], None) == good[0].with_name("clip.signals.csv")


def test_bad_inputs_are_listed_and_the_rest_processed(videos):
    root, good, bad = videos
    tasks = [(v, output_path(v, root / "out", root=root)) for v in good + bad]
    summary = run_many(tasks, BatchTask(Sensor()), jobs=1, progress=False)
    assert summary.count("done") == 3
    failed = {Path(r.video).name: r.reason for r in summary.failed}
    assert set(failed) == {p.name for p in bad}
    assert all(reason for reason in failed.values())
    assert "truncated" in failed["truncated.avi"].lower() or "end" in failed["truncated.avi"]
    for _, out in tasks[:3]:
        assert is_complete(out)
        meta = json.loads(sidecar_path(out).read_text())
        assert meta["complete"] and meta["frames_decoded"] == 12
        assert meta["camwhisker_version"] and meta["sensor"]["camera"]["fx_px"] == 1258.79
    # A rerun skips the finished files and tries the failed ones again.
    again = run_many(tasks, BatchTask(Sensor()), jobs=1, progress=False)
    assert again.count("skipped") == 3 and again.count("failed") == 4
    assert "3 done" in summary.report() and "FAILED" in summary.report()


def test_tampered_output_is_not_complete(videos):
    root, good, _ = videos
    out = output_path(good[0], root / "out", root=root)
    run_many([(good[0], out)], BatchTask(Sensor()), progress=False)
    assert is_complete(out)
    with open(out, "a") as fh:
        fh.write("half a row,")
    assert not is_complete(out)


_KILL_SCRIPT = """
import sys
from pathlib import Path
from camwhisker.run.campaign import BatchTask, run_many
from camwhisker.sensor.file import Sensor
videos = [Path(p) for p in sys.argv[2:]]
run_many([(v, Path(sys.argv[1]) / (v.stem + ".csv")) for v in videos], BatchTask(Sensor()),
         progress=False)
"""


def test_kill_9_mid_batch_then_rerun_redoes_nothing_finished(tmp_path):
    videos = []
    for i in range(6):
        p = tmp_path / f"v{i}.avi"
        shutil.copy(SAMPLE, p)
        videos.append(p)
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-c", _KILL_SCRIPT, str(out), *map(str, videos)])
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not is_complete(out / "v1.csv"):
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    done_before = {v.stem for v in videos if is_complete(out / (v.stem + ".csv"))}
    assert {"v0", "v1"} <= done_before and len(done_before) < 6
    mtimes = {s: (out / (s + ".csv")).stat().st_mtime_ns for s in done_before}
    tasks = [(v, out / (v.stem + ".csv")) for v in videos]
    summary = run_many(tasks, BatchTask(Sensor()), progress=False)
    assert summary.count("skipped") == len(done_before)
    assert summary.count("done") == 6 - len(done_before)
    assert all(is_complete(o) for _, o in tasks)
    assert all((out / (s + ".csv")).stat().st_mtime_ns == m for s, m in mtimes.items())
    leftovers = [p.name for p in out.iterdir() if p.name.startswith(".")]
    assert len(leftovers) <= 2  # at most the killed task's temporary files, never taken as output


def test_two_local_workers_and_dask_write_identical_tables(videos):
    from distributed import LocalCluster

    root, good, _ = videos
    one = [(v, output_path(v, root / "one", root=root)) for v in good]
    two = [(v, output_path(v, root / "two", root=root)) for v in good]
    dask = [(v, output_path(v, root / "dask", root=root)) for v in good]
    assert run_many(one, BatchTask(Sensor()), jobs=1, progress=False).count("done") == 3
    assert run_many(two, BatchTask(Sensor()), jobs=2, progress=False).count("done") == 3
    with LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        s = run_many(dask, BatchTask(Sensor()), scheduler=cluster.scheduler_address, progress=False)
    assert s.count("done") == 3
    for (_, a), (_, b), (_, c) in zip(one, two, dask, strict=True):
        assert a.read_bytes() == b.read_bytes() == c.read_bytes()


def test_parquet_output_has_the_same_rows(videos):
    import pyarrow.parquet as pq

    root, good, _ = videos
    csv_out = root / "x.csv"
    pq_out = root / "y.parquet"
    run_many([(good[0], csv_out), (good[1], pq_out)], BatchTask(Sensor()), progress=False)
    table = pq.read_table(pq_out)
    assert table.num_rows == 12
    assert is_complete(pq_out) and sorted(p.name for p in root.glob("y*")) == [
        "y.json",
        "y.parquet",
        "y.rest.png",
    ]
    assert json.loads(sidecar_path(pq_out).read_text())["rest_check"] == "y.rest.png"
    header = csv_out.read_text().splitlines()[0].split(",")
    assert table.column_names == header


def test_batch_command_many_inputs(videos, capsys):
    from camwhisker.cli import main

    root, good, bad = videos
    dest = root / "dest"
    rc = main(
        ["batch", str(root / "a"), str(root / "b"), str(bad[0]), "--dest", str(dest), "--quiet"]
    )
    assert rc == 1  # one input failed
    report = capsys.readouterr().out
    assert "3 videos: 2 done, 0 already complete, 1 failed" in report and bad[0].name in report
    mirrored = dest  # the inputs' folders as seen from dest's parent, root
    assert is_complete(mirrored / "a" / "clip.signals.csv")
    assert is_complete(mirrored / "b" / "clip.signals.csv")
    assert main(["batch", str(root / "a"), "--dest", str(dest), "--quiet"]) == 0
    assert "1 already complete" in capsys.readouterr().out
    assert main(["batch", str(good[0]), str(good[1]), "--out", str(root / "x.csv")]) == 2


_AFTER_OPENCV_THREADS = """
import sys
from pathlib import Path
import cv2
import numpy as np
from camwhisker.run.campaign import BatchTask, run_many
from camwhisker.sensor.file import Sensor

# OpenCV's thread pool at work in this process first, as in a notebook or a test session.
cv2.setNumThreads(2)
image = np.random.default_rng(0).integers(0, 255, (2000, 2000, 3), dtype=np.uint8)
for _ in range(3):
    cv2.GaussianBlur(image, (31, 31), 5)
out = Path(sys.argv[1])
summary = run_many([(Path(p), out / (Path(p).stem + ".csv")) for p in sys.argv[2:]],
                   BatchTask(Sensor()), jobs=2, progress=False)
print(summary.count("done"), cv2.getNumThreads())
"""


def test_workers_forked_after_opencv_used_its_threads_finish(tmp_path):
    videos = []
    for name in ("a", "b", "c"):
        videos.append(tmp_path / f"{name}.avi")
        shutil.copy(SAMPLE, videos[-1])
    # Before the fix a forked worker hung in cv2.getNumThreads (the pool's condition
    # variables copied mid-wait): 12-frame clips take ~2 s, so 120 s means hung.
    done = subprocess.run([sys.executable, "-c", _AFTER_OPENCV_THREADS, str(tmp_path / "out"),
                           *map(str, videos)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    # All three done, and this process's OpenCV back on its two threads.
    assert done.stdout.split() == ["3", "2"]
