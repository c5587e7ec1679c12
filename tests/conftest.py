"""Fixtures that several test files share, each built once per test session.

Under pytest-xdist each file runs on one worker (``--dist loadfile``), so a shared
fixture is built by the first worker that asks for it, in a folder beside the workers'
own, under a file lock; the other worker waits for it and reads it. Each is read-only to
the tests that use it.
"""

from __future__ import annotations

import os
import pickle
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from filelock import FileLock

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENT = ROOT / "sample_frames" / "experiment"
BUILD = ROOT / "sample_frames" / "build"


def _built_once(tmp_path_factory, worker_id: str, name: str, build: Callable[[Path], object]):
    """``build(folder)``'s result and its folder, built by one worker of the session.

    The result is pickled beside the folder last: a folder without it is a build that
    failed or is under way, and is built again."""
    if worker_id == "master":  # no workers: the session's own temporary folder
        folder = tmp_path_factory.mktemp(name)
        return build(folder), folder
    shared = tmp_path_factory.getbasetemp().parent  # the session's, above each worker's
    folder, done = shared / name, shared / f"{name}.pickle"
    with FileLock(str(shared / f"{name}.lock")):
        if not done.is_file():
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir()
            done.write_bytes(pickle.dumps(build(folder)))
    return pickle.loads(done.read_bytes()), folder


def _user_folder(dest: Path) -> Path:
    """Videos and stage logs of the bundled experiment, and one sensor file."""
    dest.mkdir()
    for f in [*EXPERIMENT.glob("*.mp4"), *EXPERIMENT.glob("*.stage.csv")]:
        (dest / f.name).symlink_to(f)
    shutil.copy(EXPERIMENT / "bottle_left.sensor.toml", dest / "sensor.toml")
    return dest


def _experiment_and_chain(root: Path) -> dict:
    """``camwhisker experiment`` on the bundled recordings alone (``root/out``), then
    chain on the bundled experiment (``root/chain``), reusing the experiment's signal
    tables: chain's batch skips complete outputs, so the videos are tracked once."""
    from camwhisker.bench.chain import run_chain
    from camwhisker.cli import main

    folder = _user_folder(root / "recordings")
    assert main(["experiment", str(folder), "--out", str(root / "out"), "--quiet"]) == 0
    shutil.copytree(root / "out" / "signals", root / "chain" / "signals")
    return run_chain(EXPERIMENT, root / "chain", jobs=2, progress=False)


@pytest.fixture(scope="session")
def experiment_run(tmp_path_factory, worker_id):
    """(chain's summary, the folder): ``recordings/`` (the user's folder), ``out/``
    (experiment's outputs) and ``chain/`` (chain's outputs)."""
    return _built_once(tmp_path_factory, worker_id, "experiment_run", _experiment_and_chain)



def _clip_with_the_true_file(folder: Path) -> int:
    """batch on the bundled build's clip with its true sensor file: ``folder/clip_true.csv``."""
    from camwhisker.cli import main

    return main(["batch", str(BUILD / "clip.mp4"), "--sensor", str(BUILD / "true.sensor.toml"),
                 "--out", str(folder / "clip_true.csv")])  # fmt: skip


@pytest.fixture(scope="session")
def build_clip_true(tmp_path_factory, worker_id):
    """(batch's exit status, its table): the bundled build's clip tracked with the true file."""
    rc, folder = _built_once(tmp_path_factory, worker_id, "build_clip_true",
                             _clip_with_the_true_file)  # fmt: skip
    return rc, folder / "clip_true.csv"


# Where the install's compiled kernels are missing (camwhisker.kernels), numba's JIT
# compiles them once, before any test needs them: each xdist worker, and each command a
# test starts before the cache is written, would compile them again (~25 s of a core
# each). The controller starts the compile beside the workers' collection; each worker
# waits for it before its first test.
WARM_DONE_ENV = "CAMWHISKER_TEST_KERNELS_CACHED"
WARM_TIMEOUT_S = 600.0  # a bound on waiting only: the compile takes ~25 s, ~60 s when loaded
WARM_UP = """
import itertools, sys
from pathlib import Path
done, root = sys.argv[1:]
try:
    from camwhisker.io.sources import open_source
    from camwhisker.sensor.file import load_sensor
    from camwhisker.vision.stream import track
    video = open_source(f"{root}/sample_frames/nominal_mjpg.avi")
    # Three frames: the start (detection, the tip, the pose) and LK's updates after it.
    frames = (f.image for f in itertools.islice(video, 3))
    list(track(frames, load_sensor(f"{root}/sample_frames/nominal_mjpg.sensor.toml")))
finally:
    Path(done).touch()
"""


#: Each worker computes on one thread: two workers' pools of two threads each (BLAS,
#: OpenMP under torch, OpenCV) would spin against each other on two cores.
ONE_THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                  "OPENCV_FOR_THREADS_NUM": "1"}  # fmt: skip


def pytest_configure(config):
    if hasattr(config, "workerinput") or not config.getoption("numprocesses", None):
        return  # a worker, or a run without workers: its tests compile where they need to
    for key, value in ONE_THREAD_ENV.items():
        os.environ.setdefault(key, value)  # read by the workers, started after this hook
    from camwhisker.kernels import compiled_module

    if compiled_module() is not None:
        return  # the install compiled them: nothing to warm up
    done = Path(tempfile.mkdtemp(prefix="camwhisker-kernels-")) / "done"
    os.environ[WARM_DONE_ENV] = str(done)  # the workers inherit the controller's environment
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get(
        "PYTHONPATH", "")])}
    config._camwhisker_warm_up = subprocess.Popen(  # waited for in pytest_unconfigure
        [sys.executable, "-c", WARM_UP, str(done), str(ROOT)], env=env,
        stdout=subprocess.DEVNULL)


def pytest_unconfigure(config):
    proc = getattr(config, "_camwhisker_warm_up", None)
    if proc is not None:
        proc.wait()
        shutil.rmtree(Path(os.environ.pop(WARM_DONE_ENV)).parent, ignore_errors=True)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtestloop(session):
    done = os.environ.get(WARM_DONE_ENV)
    if done and hasattr(session.config, "workerinput"):
        deadline = time.monotonic() + WARM_TIMEOUT_S
        while not Path(done).exists() and time.monotonic() < deadline:
            time.sleep(0.1)
    yield
