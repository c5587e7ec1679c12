"""Durable writes (files/atomic.py): fsync before each rename and of its folder, seen by
strace in a real ``batch``; a real full disk (a 1.25 MiB tmpfs) in the middle of a batch.

strace must be installed (Debian package ``strace``): without it the strace test fails
saying so. The full disk is a tmpfs mounted for the test (root); where mounting is not
allowed, the same run under RLIMIT_FSIZE (the kernel refuses the write with EFBIG).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from camwhisker.files.atomic import atomic_path, atomic_write_text, durable_replace
from camwhisker.run.campaign import is_complete

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_frames"
CLIP = SAMPLES / "nominal.mp4"
SENSOR = SAMPLES / "nominal.sensor.toml"
#: Bound on one batch of the 90-frame clip (s): a guard against a hang, not a measurement.
RUN_S = 600


def _cli(*args, preexec=None):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "camwhisker.cli", *map(str, args)], env=env,
                          capture_output=True, text=True, timeout=RUN_S,
                          preexec_fn=preexec)  # fmt: skip


def _batch_args(out: Path):
    return ["batch", CLIP, "--sensor", SENSOR, "--out", out, "--quiet"]


# ----------------------------------------------------------------- strace
def _strace() -> str:
    path = shutil.which("strace")
    if path is None:
        pytest.fail("strace is not installed: apt-get install strace (README's test command)")
    return path


def test_batch_fsyncs_each_file_before_its_rename_and_the_folder_after(tmp_path):
    out = tmp_path / "out" / "n.csv"
    trace = tmp_path / "trace"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    cmd = [_strace(), "-f", "-qq", "-y", "-e", "signal=none", "-o", str(trace),
           "-e", "trace=fsync,fdatasync,rename,renameat,renameat2",
           sys.executable, "-m", "camwhisker.cli", *map(str, _batch_args(out))]  # fmt: skip
    run = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=RUN_S)
    assert run.returncode == 0, run.stderr
    folder = str(out.parent)
    synced: list[str] = []  # paths fsynced so far, in order
    renames = 0
    for line in trace.read_text().splitlines():
        if m := re.search(r"\b(?:fsync|fdatasync)\(\d+<(.*)>\)\s+= 0", line):
            synced.append(m.group(1))
        elif (m := re.search(r'rename(?:at2?)?\(.*"([^"]+)",.*"([^"]+)".*= 0', line)) and (
            os.path.dirname(m.group(2)) == folder
        ):
            src = m.group(1)
            assert src in synced, f"renamed {src} into place without an fsync"
            renames += 1
            synced.append(f"renamed {m.group(2)}")  # the folder's fsync must come after this
    # The table, its sidecar and the rest frame's image: three renames, each fsynced.
    assert renames == 3
    marks = [i for i, s in enumerate(synced) if s.startswith("renamed ")]
    for i in marks:  # each rename is followed by an fsync of its folder
        assert folder in synced[i + 1:], f"no fsync of {folder} after {synced[i]}"
    names = sorted(p.name for p in out.parent.iterdir())
    assert names == ["n.csv", "n.json", "n.rest.png"]  # no temporary file left


# -------------------------------------------------------------- full disk
def _mount_tmpfs(mnt: Path, size_k: int) -> bool:
    mnt.mkdir()
    mount = shutil.which("mount")
    if os.geteuid() != 0 or mount is None:
        return False
    r = subprocess.run([mount, "-t", "tmpfs", "-o", f"size={size_k}k", "tmpfs", str(mnt)],
                       capture_output=True)  # fmt: skip
    return r.returncode == 0


def _limit_file_size(limit: int):
    """preexec: writes past ``limit`` bytes fail with EFBIG (the signal would kill)."""

    def apply():
        import resource

        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return apply


@pytest.fixture
def small_disk(tmp_path):
    """(folder, preexec, what): a 1.25 MiB tmpfs, else a 300 kB file size limit."""
    mnt = tmp_path / "mnt"
    if _mount_tmpfs(mnt, 1280):
        yield mnt, None, "tmpfs"
        subprocess.run(["umount", str(mnt)], check=True)
    else:  # the rest image (~840 kB) is larger than the limit; the tables are not
        yield mnt, _limit_file_size(300_000), "RLIMIT_FSIZE"


def _files(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())


def test_a_full_disk_in_batch_names_the_file_and_keeps_finished_outputs(tmp_path, small_disk):
    dest, preexec, what = small_disk
    for name in ("a", "b"):  # two copies of the clip: ~850 kB of outputs each
        (tmp_path / name).mkdir()
        shutil.copy(CLIP, tmp_path / name / "v.mp4")
    args = ["batch", tmp_path / "a", tmp_path / "b", "--sensor", SENSOR, "--dest", dest, "--quiet"]
    if preexec is not None:  # a limit per file fails both videos: the first done unlimited
        assert _cli(*args[:2], *args[3:]).returncode == 0
    run = _cli(*args, preexec=preexec)
    print(what, run.stdout, run.stderr)
    assert run.returncode == 1, run.stderr  # finished, one video failed
    first, second = dest / "a" / "v.signals.csv", dest / "b" / "v.signals.csv"
    # The first video fits: complete (its sidecar's size and SHA-256 match the table).
    assert is_complete(first)
    meta = json.loads(first.with_suffix(".json").read_text())
    assert meta["frames"] == 90  # every frame of the clip
    # The second one's rest image does not: the message names that file, nothing of it left.
    errno_text = "No space left on device" if what == "tmpfs" else "File too large"
    assert f"{errno_text}: '{second.with_name('v.signals.rest.png')}'" in run.stdout
    assert _files(dest) == ["a/v.signals.csv", "a/v.signals.json", "a/v.signals.rest.png"]


def test_a_full_disk_with_out_is_exit_2_naming_the_file(tmp_path, small_disk):
    dest, preexec, what = small_disk
    out = dest / "n.csv"
    if what == "tmpfs":  # leave 200 kB: the table fits, the rest image does not
        filler = dest / "filler"
        filler.write_bytes(b"\0" * (1280 * 1024 - 200_000))
    run = _cli(*_batch_args(out), preexec=preexec)
    assert run.returncode == 2
    msg = run.stderr.strip().splitlines()[-1]
    assert msg.startswith("camwhisker batch: error: ")
    assert str(dest / "n.rest.png") in msg and "Traceback" not in run.stderr
    assert _files(dest) == (["filler"] if what == "tmpfs" else [])  # no partial file left


# ------------------------------------------------------------ unit checks
def test_an_error_writing_names_the_target_not_the_temporary_file(tmp_path):
    target = tmp_path / "t.txt"
    with pytest.raises(OSError) as err, atomic_path(target) as tmp:
        tmp.write_text("half")
        os.unlink(tmp)  # the temporary file vanished: the fsync before the rename fails
    assert err.value.filename == str(target) and err.value.errno == 2  # ENOENT
    assert list(tmp_path.iterdir()) == []


def test_an_input_error_inside_keeps_its_own_name(tmp_path):
    missing = tmp_path / "missing.csv"
    with pytest.raises(FileNotFoundError) as err, atomic_path(tmp_path / "t.txt"):
        missing.read_text()
    assert err.value.filename == str(missing)  # the input, not the output


def test_durable_replace_moves_and_names_the_target(tmp_path):
    src = tmp_path / "a.txt"
    atomic_write_text(src, "x")
    assert durable_replace(src, tmp_path / "b.txt").read_text() == "x"
    with pytest.raises(FileNotFoundError) as err:
        durable_replace(src, tmp_path / "c.txt")
    assert err.value.filename == str(tmp_path / "c.txt")
