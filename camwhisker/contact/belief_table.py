"""Contact belief of a signal table: its rest frames, eta, and the table with the belief's
columns added (docs/sensor.md section 6.2), with a sidecar listing the onsets.

The rest frames are the ones the stream averaged for its rest reference
(:mod:`camwhisker.vision.stream`): the sidecar ``S.json`` records each reference's
first frame and how many frames it used (``rest_references``). A table without
a sidecar (simulated, or from another program) names them with ``rest_frames``
(the first N rows), or skips them with a given eta (the paper's way: from
no-contact trials).
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camwhisker import __version__
from camwhisker.contact.belief import (
    ETA_FACTOR,
    ETA_FLOOR_DEG,
    ETA_QUANTILE,
    Onset,
    eta_from_rest,
    eta_source,
    find_onsets,
)
from camwhisker.files import jsonfile
from camwhisker.files.atomic import atomic_path
from camwhisker.io.signals import SignalTableError, read_signal_table, sidecar_path

__all__ = ["BELIEF_COLUMNS", "TableBelief", "rest_rows", "table_belief", "write_belief_table"]

#: Added last to the signal table: eq. 1's belief and the contact flag (0/1).
BELIEF_COLUMNS = ("contact_b", "contact")


@dataclass(frozen=True)
class TableBelief:
    """A signal table's belief: eta and where it came from, per-row b and flag, onsets."""

    source: str
    eta_deg: float
    eta_from: str
    rest_rows: np.ndarray
    t_s: np.ndarray
    b: np.ndarray
    flag: np.ndarray
    onsets: list[Onset]


def rest_rows(table: dict, rest_frames: int | None = None) -> np.ndarray:
    """Row indices of the rest frames: the first ``rest_frames`` rows, else those the
    sidecar's ``rest_references`` name.

    Raises
    ------
    SignalTableError
        No sidecar, or one that names no rest frames present in the table.
    """
    source = table["source"]
    if rest_frames is not None:
        if rest_frames < 1:
            raise SignalTableError(f"rest frames must be >= 1, got {rest_frames}")
        return np.arange(min(rest_frames, table["t_s"].size))
    side = sidecar_path(source)
    try:
        record = json.loads(side.read_text())
    except FileNotFoundError:
        raise SignalTableError(f"{source}: no sidecar {side} to name the rest frames; "
                               f"give the rest frames or eta") from None  # fmt: skip
    except (OSError, ValueError) as exc:
        raise SignalTableError(f"{side}: cannot read ({exc})") from None
    refs = record.get("rest_references") if isinstance(record, dict) else None
    if not refs:
        raise SignalTableError(f"{side}: key rest_references: no rest frames recorded")
    frames = table["frame"]
    rows = []
    for ref in refs:
        try:
            first, used = int(ref["frame"]), int(ref["frames_used"])
        except (KeyError, TypeError, ValueError):
            raise SignalTableError(f"{side}: key rest_references: {ref!r} lacks "
                                   f"frame or frames_used") from None  # fmt: skip
        rows.append(np.flatnonzero((frames >= first) & (frames < first + used)))
    rows = np.unique(np.concatenate(rows))
    if rows.size == 0:
        raise SignalTableError(f"{side}: key rest_references: its frames are not in {source}")
    return rows


def table_belief(
    path: str | Path, rest_frames: int | None = None, eta_deg: float | None = None
) -> TableBelief:
    """Belief, contact flag and onsets of a signal table (|d| = phi_deg, see
    :mod:`camwhisker.contact.belief`); eta from its rest frames unless given.

    Raises
    ------
    camwhisker.files.tables.TableError
        A missing or broken table, no sidecar or rest frames, or too few trusted ones
        (named by file and key).
    """
    table = read_signal_table(path)
    d = np.where(table["ok"], table["phi_deg"], np.nan)
    rows = np.array([], int)
    if eta_deg is not None:
        eta, eta_from = float(eta_deg), "given"
    else:
        rows = rest_rows(table, rest_frames)
        try:
            eta = eta_from_rest(d[rows])
        except ValueError as exc:
            raise SignalTableError(f"{path}: rest rows {rows[0] + 2}-{rows[-1] + 2}, "
                                   f"column phi_deg: {exc}") from None  # fmt: skip
        eta_from = eta_source(d[rows], eta)
    b, flag, onsets = find_onsets(d, eta)
    return TableBelief(str(path), eta, eta_from, rows, table["t_s"], b, flag, onsets)


def _cells(belief: TableBelief, i: int) -> list[str]:
    b = belief.b[i]
    return ["" if not np.isfinite(b) else f"{b:.4f}", str(int(belief.flag[i]))]


def write_belief_table(belief: TableBelief, out: str | Path) -> Path:
    """The signal table with :data:`BELIEF_COLUMNS` added (replaced where present), and
    ``OUT.json`` beside it (eta, rest frames, onsets); both atomic. Returns the sidecar."""
    src = Path(belief.source)
    rows = [r for r in csv.reader(io.StringIO(src.read_text(encoding="utf-8"))) if r]
    header = rows[0]
    keep = [j for j, name in enumerate(header) if name.strip() not in BELIEF_COLUMNS]
    with atomic_path(out) as tmp, open(tmp, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow([header[j] for j in keep] + list(BELIEF_COLUMNS))
        for i, row in enumerate(rows[1:]):
            writer.writerow([row[j] for j in keep] + _cells(belief, i))
    record = {
        "camwhisker_version": __version__,
        "made_by": "camwhisker.contact.belief_table.write_belief_table",
        "input": str(src),
        "deflection": "phi_deg (the tilt vector's norm, relative to rest)",
        "eta_deg": belief.eta_deg,
        "eta_from": belief.eta_from,
        "rest_rows": [int(belief.rest_rows[0]), int(belief.rest_rows[-1])]
        if belief.rest_rows.size
        else None,  # 0-based, first and last
        "constants": {"ETA_QUANTILE": ETA_QUANTILE, "ETA_FACTOR": ETA_FACTOR,
                      "ETA_FLOOR_DEG": ETA_FLOOR_DEG},
        "frames": int(belief.b.size),
        "frames_in_contact": int(belief.flag.sum()),
        "onsets": [o.as_dict(belief.t_s) for o in belief.onsets],
    }
    side = sidecar_path(out)
    with atomic_path(side) as tmp:
        tmp.write_text(jsonfile.dumps(record, indent=2) + "\n")
    return side
