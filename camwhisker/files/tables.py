"""CSV tables of named numeric columns: read into arrays, written atomically.

The low-level format every stage's tables share (stage logs, contact tables,
calibration tables, truth tables): a header row, then one row per sample;
an empty cell is NaN. Outputs are written to a temporary file in the target
folder and renamed into place, so a reader never sees half a file.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from camwhisker.files.atomic import atomic_write_text

__all__ = ["TableError", "read_header", "read_columns", "read_log", "check_times", "write_csv",
           "format_cell"]


class TableError(ValueError):
    """A table that cannot be used; the message names the file, row and column."""


def read_header(path: str | Path) -> list[str]:
    """A CSV's column names (its first row), stripped.

    Raises
    ------
    TableError
        A missing or unreadable file.
    """
    try:
        with open(path, encoding="utf-8", newline="") as fh:
            return [h.strip() for h in next(csv.reader(fh), [])]
    except OSError as exc:
        raise TableError(f"{path}: cannot read ({exc.strerror})") from exc


def read_columns(path: str | Path, columns: tuple[str, ...] | None = None,
                 optional: tuple[str, ...] = ()) -> dict:
    """Numeric columns of a CSV with a header into float arrays (empty cell -> NaN).

    Parameters
    ----------
    columns : tuple of str, optional
        The columns to read (others, e.g. free-text notes, are ignored); all if None.
    optional : tuple of str
        With ``columns``: also read these where the header has them.

    Raises
    ------
    TableError
        Missing file or column, a ragged row, or a non-numeric cell (named by row and column).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise TableError(f"{path}: cannot read ({exc.strerror})") from exc
    reader = csv.reader(io.StringIO(text))
    header = [h.strip() for h in next(reader, [])]
    if not header:
        raise TableError(f"{path}: empty file, expected a header ({', '.join(columns or ())})")
    for need in columns or ():
        if need not in header:
            raise TableError(f"{path}: row 1: missing column {need} (header: "
                             f"{', '.join(header)})")
    wanted = header if columns is None else (*columns, *(c for c in optional if c in header))
    idx = {name: header.index(name) for name in wanted}
    cols = {name: [] for name in idx}
    for i, row in enumerate(reader, start=2):
        if not row:
            continue
        if len(row) != len(header):
            raise TableError(f"{path}: row {i}: {len(row)} cells, header has {len(header)}")
        for name, j in idx.items():
            cell = row[j].strip()
            if cell == "" or cell.lower() == "nan":
                cols[name].append(math.nan)
                continue
            try:
                cols[name].append(float(cell))
            except ValueError:
                raise TableError(
                    f"{path}: row {i}, column {name}: not a number: {cell!r}") from None
    return {k: np.array(v, float) for k, v in cols.items()}


def read_log(path: str | Path, required: tuple[str, ...], optional: tuple[str, ...], what: str,
             error: type[Exception]) -> tuple[dict, list[int]]:  # fmt: skip
    """A logged CSV's columns (``required``, and ``optional`` where present) as float
    arrays, every cell a finite number, blank rows skipped; and each value's 1-based
    row (the header is row 1). Errors are ``error`` naming the file, row and column;
    ``what`` names the file's kind ("stage log")."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise error(f"{path}: cannot read {what} ({exc.strerror})") from exc
    rows = list(csv.reader(text.splitlines()))
    if not rows:
        raise error(f"{path}: empty file, expected header {','.join(required)}")
    header = [h.strip() for h in rows[0]]
    for need in required:
        if need not in header:
            raise error(f"{path}: row 1: missing column {need} (header: {', '.join(header)})")
    cols = {name: header.index(name) for name in required + optional if name in header}
    data = {name: [] for name in cols}
    row_of = []
    for i, row in enumerate(rows[1:], start=2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(header):
            raise error(f"{path}: row {i}: {len(row)} cells, header has {len(header)}")
        for name, j in cols.items():
            cell, where = row[j].strip(), f"{path}: row {i}, column {name}"
            try:
                value = float(cell)
            except ValueError:
                raise error(f"{where}: not a number: {cell!r}") from None
            if not math.isfinite(value):
                raise error(f"{where}: not a finite number: {cell!r}")
            data[name].append(value)
        row_of.append(i)
    return {k: np.array(v, float) for k, v in data.items()}, row_of


def check_times(t_s: np.ndarray, rows: list[int], source: str, max_gap_s: float,
                error: type[Exception]) -> None:
    """A log's times strictly increasing with no gap over ``max_gap_s``; ``error`` naming
    the file, the row (``rows[i]`` numbers sample i) and column t_s otherwise."""
    dt = np.diff(t_s)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        k = bad[0]
        what = "duplicate time" if dt[k] == 0 else "time goes backwards (unsorted)"
        raise error(f"{source}: row {rows[k + 1]}, column t_s: {what}: "
                    f"{t_s[k + 1]!r} after {t_s[k]!r}")  # fmt: skip
    gap = np.flatnonzero(dt > max_gap_s)
    if gap.size:
        k = gap[0]
        raise error(f"{source}: row {rows[k + 1]}, column t_s: gap of {dt[k]:.3f} s "
                    f"(more than {max_gap_s:g} s without a sample)")  # fmt: skip


def format_cell(value, digits: int = 6) -> str:
    """A CSV cell: empty for NaN/None, integers plain, floats with ``digits`` significant digits."""
    if value is None:
        return ""
    if isinstance(value, str):  # a text column (the contact table's doubt)
        return value
    if isinstance(value, bool | np.bool_):
        return "1" if value else "0"
    if isinstance(value, int | np.integer):
        return str(int(value))
    v = float(value)
    if not math.isfinite(v):
        return ""
    return f"{v:.{digits}g}"


def write_csv(path: str | Path, columns: dict, digits: int = 6) -> None:
    """Write equal-length columns as CSV (atomically); NaN cells are empty.

    No comment lines: readers of the docs/sensor.md tables expect the header first,
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
