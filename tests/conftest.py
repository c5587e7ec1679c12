"""Fixtures that several test files share, each built once per test session.

Under pytest-xdist each file runs on one worker (``--dist loadfile``), so a shared
fixture is built by the first worker that asks for it, in a folder beside the workers'
own, under a file lock; the other worker waits for it and reads it. Each is read-only to
the tests that use it.
"""

from __future__ import annotations

import pickle
import shutil
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
