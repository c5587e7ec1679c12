"""Files of the contact back end: signal tables in, CSV tables out, atomic writes.

Every output is written to a temporary file in the target folder and renamed
into place, so a reader never sees half a file.
"""

from __future__ import annotations

import csv
import io
import math
import os
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["SignalTableError", "read_signal_table", "write_csv", "atomic_write_text",
           "atomic_write_bytes", "format_cell"]

SIGNAL_COLUMNS = ("frame", "t_s", "dz_mm", "phi_deg", "theta_deg", "ok")
_UMASK = os.umask(0o022)
os.umask(_UMASK)


class SignalTableError(ValueError):
    """A signal table that cannot be used; the message names the file, row and column."""


def read_signal_table(path: str | Path) -> dict:
    """Read a signal table (SENSOR.md section 6) into float arrays (empty cell -> NaN).

    ``ok`` becomes a bool array; rows with ok = 0 keep their (NaN) values.

    Raises
    ------
    SignalTableError
        Missing file or column, a non-numeric cell, or t_s missing or not increasing.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise SignalTableError(f"{path}: cannot read signal table ({exc.strerror})") from exc
    reader = csv.reader(io.StringIO(text))
    header = [h.strip() for h in next(reader, [])]
    for need in SIGNAL_COLUMNS:
        if need not in header:
            raise SignalTableError(f"{path}: row 1: missing column {need!r} (header: {header})")
    idx = {name: header.index(name) for name in SIGNAL_COLUMNS}
    cols = {name: [] for name in SIGNAL_COLUMNS}
    for i, row in enumerate(reader, start=2):
        if not row:
            continue
        if len(row) != len(header):
            raise SignalTableError(f"{path}: row {i}: {len(row)} cells, header has {len(header)}")
        for name, j in idx.items():
            cell = row[j].strip()
            if cell == "" or cell.lower() == "nan":
                cols[name].append(math.nan)
                continue
            try:
                cols[name].append(float(cell))
            except ValueError:
                raise SignalTableError(
                    f"{path}: row {i}, column {name}: not a number: {cell!r}") from None
    out = {k: np.array(v, float) for k, v in cols.items()}
    t = out["t_s"]
    if t.size == 0:
        raise SignalTableError(f"{path}: no rows")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise SignalTableError(f"{path}: row {bad[0] + 2}, column t_s: empty")
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        raise SignalTableError(f"{path}: row {back[0] + 3}, column t_s: not increasing")
    out["ok"] = np.nan_to_num(out["ok"], nan=0.0) == 1.0
    out["source"] = str(path)
    return out


def format_cell(value, digits: int = 6) -> str:
    """A CSV cell: empty for NaN/None, integers plain, floats with ``digits`` significant digits."""
    if value is None:
        return ""
    if isinstance(value, bool | np.bool_):
        return "1" if value else "0"
    if isinstance(value, int | np.integer):
        return str(int(value))
    v = float(value)
    if not math.isfinite(v):
        return ""
    return f"{v:.{digits}g}"


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write to a temporary file beside ``path``, then rename it into place."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; give the usual file mode
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def write_csv(path: str | Path, columns: dict, digits: int = 6) -> None:
    """Write equal-length columns as CSV (atomically); NaN cells are empty.

    No comment lines: readers of the SENSOR.md tables expect the header first,
    so provenance goes into a sidecar file.
    """
    names = list(columns)
    arrays = [np.asarray(columns[n]) for n in names]
    n = {a.shape[0] for a in arrays}
    if len(n) > 1:
        raise ValueError(f"columns have different lengths: {dict(zip(names, n, strict=False))}")
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(names)
    for row in zip(*arrays, strict=True):
        w.writerow([format_cell(v, digits) for v in row])
    atomic_write_text(path, buf.getvalue())
