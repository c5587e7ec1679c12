"""Atomic file output: a reader never sees half a file, a crash never leaves one for long.

Everything the package writes goes through :func:`atomic_path`: the content
goes to a hidden temporary name in the target folder (``.STEM.XXXXXXXX.tmp.SUFFIX``),
which is fsynced and renamed into place only once it is complete, and the
folder is fsynced after the rename, so after a power cut the name holds the
whole file or the old one, never an empty one. The writer holds an
exclusive ``flock`` on the temporary file while it writes; the kernel drops it
when the writer dies (kill -9 included), so :func:`remove_stale_temps` can tell
a temporary file left by a dead writer from one still being written.

An OSError while writing names the target file (not its temporary name), so
the commands print which file the disk refused.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import re
import tempfile
from collections.abc import Iterator
from pathlib import Path

__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_text", "remove_stale_temps",
           "durable_replace", "sync_file", "sync_folder"]

# The process's umask: os.umask reads it only by setting it, so set it back at once.
_UMASK = os.umask(0o022)
os.umask(_UMASK)

#: The marker before the target's suffix; the suffix is kept so writers that pick a
#: format by it (OpenCV, PyAV) still see the target's.
TEMP_MARK = ".tmp"
# ".STEM." + mkstemp's 8 random characters + ".tmp" + the target's suffix.
_TEMP_NAME = re.compile(r"\..+\.[a-z0-9_]{8}" + re.escape(TEMP_MARK) + r"(\.[^.]*)?")


#: Errors of a write with no file name attached (a full disk, a quota, a file size
#: limit, a failing device): inside :func:`atomic_path` they are the target's.
_WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO, errno.EROFS})


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix); fsync it, rename it into
    place and fsync the folder on success.

    On an exception the temporary file is removed and ``path`` is left as it was;
    an OSError of the write is raised again naming ``path``. The temporary file is
    locked (``flock``) until then, marking it as in use.
    """
    path = Path(path)
    try:
        created = not path.parent.is_dir()
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = _locked_temp(path)
    except OSError as exc:
        raise _naming(exc, path, None) from exc
    try:
        yield Path(tmp)
        sync_file(tmp)  # the data on the disk before the name points at it
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; give the usual file mode
        os.replace(tmp, path)
        sync_folder(path.parent)  # the rename itself on the disk
        if created:
            sync_folder(path.parent.parent)
    except OSError as exc:
        raise _naming(exc, path, tmp) from exc
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        os.close(fd)  # releases the lock


def _naming(exc: OSError, path: Path, tmp: str | None) -> OSError:
    """``exc`` naming ``path`` where it is about the temporary file or an unnamed write
    (``tmp`` None: creating the temporary file, always about ``path``)."""
    if tmp is not None and exc.filename is not None and os.fspath(exc.filename) != tmp:
        return exc  # the body's own error (reading an input, the folder): its own file
    if tmp is not None and exc.filename is None and exc.errno not in _WRITE_ERRNOS:
        return exc
    return _named(exc, path)


def _named(exc: OSError, path: Path) -> OSError:
    if exc.errno is None:  # a library's OSError without a code (PyAV, OpenCV): its text
        return OSError(f"{path}: {exc}")
    return OSError(exc.errno, exc.strerror or os.strerror(exc.errno), str(path))


def sync_file(path: str | Path) -> None:
    """fsync the file at ``path`` (opened again: a writer may have closed its own)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def sync_folder(folder: str | Path) -> None:
    """fsync a folder, so the names created or renamed in it are on the disk."""
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def durable_replace(src: str | Path, dst: str | Path) -> Path:
    """Rename a finished (synced) file to ``dst`` and fsync the folders; returns ``dst``."""
    src, dst = Path(src), Path(dst)
    try:
        os.replace(src, dst)
        sync_folder(dst.parent)
        if src.parent.resolve() != dst.parent.resolve():
            sync_folder(src.parent)
    except OSError as exc:
        raise _named(exc, dst) from exc
    return dst


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
