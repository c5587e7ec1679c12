"""Atomic file output: a reader never sees half a file, a crash never leaves one for long.

Everything the package writes goes through :func:`atomic_path`: the content
goes to a hidden temporary name in the target folder (``.STEM.XXXXXXXX.tmp.SUFFIX``),
which is renamed into place only once it is complete. The writer holds an
exclusive ``flock`` on the temporary file while it writes; the kernel drops it
when the writer dies (kill -9 included), so :func:`remove_stale_temps` can tell
a temporary file left by a dead writer from one still being written.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import tempfile
from collections.abc import Iterator
from pathlib import Path

__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_text", "remove_stale_temps"]

# The process's umask: os.umask reads it only by setting it, so set it back at once.
_UMASK = os.umask(0o022)
os.umask(_UMASK)

#: The marker before the target's suffix; the suffix is kept so writers that pick a
#: format by it (OpenCV, PyAV) still see the target's.
TEMP_MARK = ".tmp"
# ".STEM." + mkstemp's 8 random characters + ".tmp" + the target's suffix.
_TEMP_NAME = re.compile(r"\..+\.[a-z0-9_]{8}" + re.escape(TEMP_MARK) + r"(\.[^.]*)?")


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix); rename it into place on success.

    On an exception the temporary file is removed and ``path`` is left as it was.
    The temporary file is locked (``flock``) until then, marking it as in use.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = _locked_temp(path)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; give the usual file mode
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        os.close(fd)  # releases the lock


def _locked_temp(path: Path) -> tuple[int, str]:
    """A new temporary file for ``path`` and its open descriptor, locked."""
    while True:
        fd, tmp = tempfile.mkstemp(
            prefix=f".{path.stem}.", suffix=TEMP_MARK + path.suffix, dir=path.parent
        )
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError:  # a filesystem without locks: unmarked, so never taken for stale
            return fd, tmp
        if os.fstat(fd).st_nlink:
            return fd, tmp
        # A cleaner took it for stale between mkstemp and flock: take another name.
        os.close(fd)


def remove_stale_temps(folder: str | Path) -> list[Path]:
    """Remove the temporary files of :func:`atomic_path` in ``folder`` that no live
    writer holds (left by a process that was killed); returns them."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    removed = []
    for p in sorted(folder.iterdir()):
        if _TEMP_NAME.fullmatch(p.name) and _remove_if_unlocked(p):
            removed.append(p)
    return removed


def _remove_if_unlocked(path: Path) -> bool:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # gone meanwhile (renamed into place) or not ours to read
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:  # a live writer holds it (or the filesystem cannot say)
        os.close(fd)
        return False
    try:
        # Unlink only what is still this file: it may have been renamed into place.
        same = os.path.samestat(os.fstat(fd), os.stat(path))
        if same:
            os.unlink(path)
        return same
    except FileNotFoundError:
        return False
    finally:
        os.close(fd)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))
