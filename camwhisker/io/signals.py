"""The signal table (docs/sensor.md section 6): its columns, rows, writer, reader and sidecar.

One row per frame, in frame order: ``frame, t_s, dz_mm, phi_deg, theta_deg,
ok`` (the columns every reader may rely on), then diagnostics, then, where a
spring stiffness is given (``--springs``), the forces ``fz_mN, mb_Nmm``
(:data:`FORCE_COLUMNS`; docs/sensor.md section 6.1). Untrusted
values are empty cells, never numbers; so is theta where phi is too small to
define it. Batch, live and replay write the table through
:class:`SignalWriter`, the contact back end reads it with
:func:`read_signal_table`.

Beside ``OUT.csv``, the sidecar ``OUT.json`` records how the table was made
(version, input, clock, rest frame and the rest references with their
mismatch checks, counts, problems, options, thresholds, sensor, columns),
built by :func:`sidecar` for every writer; its common part,
:func:`provenance`, is every sidecar's (the overlay's too).
"""

from __future__ import annotations

import csv
import dataclasses
import math
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from camwhisker import __version__
from camwhisker.files import jsonfile
from camwhisker.files.atomic import atomic_path
from camwhisker.files.tables import TableError, read_columns
from camwhisker.sensor.file import Sensor, sensor_to_dict

if TYPE_CHECKING:
    from camwhisker.sensor.springs import Stiffness
    from camwhisker.vision.tracker import FrameResult, FrontEndOptions

__all__ = [
    "SIGNAL_COLUMNS", "REQUIRED_COLUMNS", "FORCE_COLUMNS", "table_columns", "SignalTableError",
    "signal_row", "SignalWriter", "write_signals", "read_signal_table", "signal_columns",
    "sidecar_path", "provenance", "sidecar", "write_sidecar",
]  # fmt: skip

#: Required columns first (docs/sensor.md section 6), then diagnostics.
SIGNAL_COLUMNS = (
    "frame", "t_s", "dz_mm", "phi_deg", "theta_deg", "ok",
    "sx_mm", "sy_mm", "phi_sigma_deg", "n_corners", "rms_px", "note",
)  # fmt: skip
#: The columns docs/sensor.md section 6 promises; readers need no others.
REQUIRED_COLUMNS = SIGNAL_COLUMNS[:6]
#: Optional, last, where a spring stiffness is given: F_z = k_z dz, M_b = k_phi phi.
FORCE_COLUMNS = ("fz_mN", "mb_Nmm")


def table_columns(springs: Stiffness | None = None) -> tuple[str, ...]:
    """The signal table's columns: :data:`FORCE_COLUMNS` added where ``springs`` is given."""
    return SIGNAL_COLUMNS + (FORCE_COLUMNS if springs is not None else ())


class SignalTableError(TableError):
    """A signal table that cannot be used; the message names the file, row and column."""


def _cell(x: float, fmt: str) -> str:
    return "" if x is None or not math.isfinite(x) else format(x, fmt)


def signal_row(t_s: float, r: FrameResult, springs: Stiffness | None = None) -> list:
    """One row of the signal table (:func:`table_columns`) for a front-end result.

    Untrusted estimates (ok = 0) are empty cells, never numbers.
    """
    ok = bool(r.ok)
    forces = []
    if springs is not None:
        forces = [_cell(float(springs.fz_mN(r.dz_mm)), ".5g") if ok else "",
                  _cell(float(springs.mb_Nmm(r.phi_deg)), ".5g") if ok else ""]
    return [
        r.frame, _cell(t_s, ".6f"),
        _cell(r.dz_mm, ".5f") if ok else "",
        _cell(r.phi_deg, ".5f") if ok else "",
        _cell(r.theta_deg, ".3f") if ok else "",
        int(ok),
        _cell(r.sx_mm, ".5f") if ok else "",
        _cell(r.sy_mm, ".5f") if ok else "",
        _cell(r.phi_sigma_deg, ".5f"),
        r.n_corners, _cell(r.rms_px, ".3f"), r.reason, *forces,
    ]  # fmt: skip


class SignalWriter:
    """The signal table, written row by row; it counts the rows and the trusted rows.

    Parameters
    ----------
    path : path
        Written directly; wrap it in :func:`~camwhisker.files.atomic.atomic_path` where a
        reader must never see a partial table.
    flush : bool
        Flush after every row, so the table can be read while it grows (live).
    springs : Stiffness, optional
        Adds the forces' columns (:data:`FORCE_COLUMNS`).
    extra : tuple of str
        Columns written last (live contact: :mod:`camwhisker.live.contact`).
    """

    def __init__(self, path: str | Path, flush: bool = False, springs: Stiffness | None = None,
                 extra: tuple[str, ...] = ()):  # fmt: skip
        self.path = Path(path)
        self.flush = flush
        self.springs = springs
        self._fh = open(self.path, "w", newline="")  # noqa: SIM115 - closed in close()
        self._csv = csv.writer(self._fh)
        self._csv.writerow(table_columns(springs) + tuple(extra))
        if flush:
            self._fh.flush()
        self.rows = 0
        self.rows_ok = 0

    def write(self, t_s: float, r: FrameResult, extra: list[str] = ()) -> None:
        """One row; ``extra``: the cells of the ``extra`` columns, already formatted."""
        self._csv.writerow(signal_row(t_s, r, self.springs) + list(extra))
        if self.flush:
            self._fh.flush()
        self.rows += 1
        self.rows_ok += bool(r.ok)

    def close(self) -> None:
        if not self._fh.closed:
            self._fh.close()

    def __enter__(self) -> SignalWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def write_signals(path: str | Path, rows: Iterable[tuple[float, FrameResult]],
                  springs: Stiffness | None = None) -> tuple[int, int]:  # fmt: skip
    """Write (t_s, result) rows as the signal table (the forces too where ``springs`` is
    given); returns (rows, rows ok).

    ``path`` is written directly; wrap it in an atomic path for safety.
    """
    with SignalWriter(path, springs=springs) as writer:
        for t_s, r in rows:
            writer.write(t_s, r)
    return writer.rows, writer.rows_ok


def read_signal_table(path: str | Path) -> dict:
    """Read a signal table's required columns into float arrays (empty cell -> NaN).

    ``ok`` becomes a bool array; rows with ok = 0 keep their (NaN) values;
    ``source`` is the path read.

    Raises
    ------
    camwhisker.files.tables.TableError
        Missing file or column, a non-numeric cell, or t_s missing or not increasing
        (:class:`SignalTableError` for the last two).
    """
    return signal_columns(read_columns(path, REQUIRED_COLUMNS), str(path))


def signal_columns(out: dict, source: str) -> dict:
    """A signal table's columns (float arrays, as :func:`read_signal_table` reads them)
    checked; rows are numbered as in a file (the header is row 1)."""
    missing = [c for c in REQUIRED_COLUMNS if c not in out]
    if missing:
        raise SignalTableError(f"{source}: no column {missing[0]}")
    t = out["t_s"]
    if t.size == 0:
        raise SignalTableError(f"{source}: no rows")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise SignalTableError(f"{source}: row {bad[0] + 2}, column t_s: empty")
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        raise SignalTableError(f"{source}: row {back[0] + 3}, column t_s: not increasing")
    out["ok"] = np.nan_to_num(out["ok"], nan=0.0) == 1.0
    out["source"] = source
    return out


def sidecar_path(out_csv: str | Path) -> Path:
    """``OUT.json`` beside ``OUT.csv``."""
    return Path(out_csv).with_suffix(".json")


def provenance(
    made_by: str, source: object, options: FrontEndOptions, sensor: Sensor, **fields: object
) -> dict:
    """How an output was made, the keys every sidecar shares: the version, the maker, the
    input, then ``fields``, then the front end's options and thresholds and the sensor.

    Parameters
    ----------
    made_by : str
        The function or class that wrote the output.
    source : str or dict
        The input (a path, or a capture's description).
    options : FrontEndOptions
    sensor : Sensor
    **fields
        The output's own fields, placed after ``input``.
    """
    # Imported here: readers of signal tables (the contact back end) need no front end.
    from camwhisker.vision import tracker

    return {
        "camwhisker_version": __version__,
        "made_by": made_by,
        "input": source,
        **fields,
        "options": dataclasses.asdict(options),
        "constants": {
            "PHI_MIN_FOR_THETA_DEG": tracker.PHI_MIN_FOR_THETA_DEG,
            "QUALITY_MIN": tracker.QUALITY_MIN,
            "MIN_CORNERS": tracker.MIN_CORNERS,
            "MAX_RMS_PX": tracker.MAX_RMS_PX,
        },
        "sensor_file": sensor.source,
        "sensor": sensor_to_dict(sensor),
    }


def sidecar(
    made_by: str,
    source: object,
    time_source: str,
    counts: tuple[int, int],
    problems: list[str],
    options: FrontEndOptions,
    sensor: Sensor,
    rest_frame: int = 0,
    rest: list | None = None,
    springs: Stiffness | None = None,
    **stage: object,
) -> dict:
    """How a signal table was made: the sidecar's record, the same keys for every writer
    (:func:`provenance` with the table's fields and its columns).

    Parameters
    ----------
    made_by, source, options, sensor
        As for :func:`provenance`.
    time_source : str
        Where t_s comes from.
    counts : (int, int)
        Rows and trusted rows.
    problems : list of str
        What went wrong without stopping the run (empty when nothing did).
    rest_frame : int
    rest : list of camwhisker.vision.stream.RestRecord, optional
        The rest references built (how many frames each used, the mismatch check);
        ``rest_frames_used`` is the first one's count.
    springs : Stiffness, optional
        The stiffness behind the forces' columns, recorded with its source.
    **stage
        The writer's own fields (a frame rate, a live session's latencies), placed
        after ``time_source``.
    """
    record = provenance(made_by, source, options, sensor, time_source=time_source, **stage,
                        rest_frame=rest_frame,
                        rest_frames_used=rest[0].frames_used if rest else None,
                        rest_references=[r.as_dict() for r in rest or []],
                        frames=counts[0], frames_ok=counts[1], problems=problems)  # fmt: skip
    if springs is not None:
        record["springs"] = {"source": springs.source, "k_z_n_per_mm": springs.k_z_n_per_mm,
                             "k_phi_nmm_per_rad": springs.k_phi_nmm_per_rad}
    record["columns"] = list(table_columns(springs))
    return record


def write_sidecar(out: str | Path, record: dict) -> Path:
    """Write ``record`` as ``out``'s JSON sidecar (atomically); returns its path."""
    path = sidecar_path(out)
    with atomic_path(path) as tmp:
        tmp.write_text(jsonfile.dumps(record, indent=2) + "\n")
    return path
