"""Force-torque logs (docs/sensor.md section 7.1): read, validate, write.

A force log is a CSV on the force sensor's own clock, one row per sample, with
header ``t_s,fz_mN`` and an optional ``mb_Nmm``: the axial force on the plate
(signed as the signal table's dz: positive pushes the plate toward the camera)
and the bending moment's magnitude about the plate's centre of rotation. The
force sensor's clock is offset from the camera's; ``offset_s`` always means

    t_camera = t_force + offset_s.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camwhisker.files.tables import check_times, read_log, write_csv

__all__ = ["ForceLogError", "ForceLog", "read_force_log", "write_force_log", "FORCE_COLUMNS"]

#: Required columns, then the optional one.
FORCE_COLUMNS = ("t_s", "fz_mN", "mb_Nmm")
# A longer gap between samples could hide a step: no stretch of it can be
# averaged like the rest, so it is an error (the stage log's rule).
MAX_GAP_S = 1.0


class ForceLogError(ValueError):
    """A force log that cannot be used; the message names the file, row and column."""


@dataclass(frozen=True)
class ForceLog:
    """A validated force log: arrays of shape (N,), times strictly increasing."""

    t_s: np.ndarray
    fz_mN: np.ndarray
    mb_Nmm: np.ndarray | None
    source: str


def read_force_log(path: str | Path) -> ForceLog:
    """Read and validate a force log CSV.

    Raises
    ------
    ForceLogError
        Missing file or column, a non-numeric, empty or non-finite cell, a
        negative ``mb_Nmm`` (a magnitude), times not strictly increasing, a gap
        over :data:`MAX_GAP_S`, or fewer than two rows. The message names the
        file and the 1-based row (the header is row 1) and column.
    """
    path = Path(path)
    data, row_of = read_log(path, FORCE_COLUMNS[:2], FORCE_COLUMNS[2:], "force log",
                            ForceLogError)  # fmt: skip
    t = data["t_s"]
    if t.size < 2:
        raise ForceLogError(f"{path}: needs at least 2 samples, got {t.size}")
    check_times(t, row_of, str(path), MAX_GAP_S, ForceLogError)
    mb = data.get("mb_Nmm")
    if mb is not None and (mb < 0).any():
        k = int(np.flatnonzero(mb < 0)[0])
        raise ForceLogError(f"{path}: row {row_of[k]}, column mb_Nmm: negative ({mb[k]!r}); "
                            "it is the bending moment's magnitude")
    return ForceLog(t_s=t, fz_mN=data["fz_mN"], mb_Nmm=mb, source=str(path))


def write_force_log(path: str | Path, log: ForceLog) -> None:
    """Write a force log (atomically); ``mb_Nmm`` only where the log has it."""
    cols = {"t_s": log.t_s, "fz_mN": log.fz_mN}
    if log.mb_Nmm is not None:
        cols["mb_Nmm"] = log.mb_Nmm
    write_csv(path, cols, digits=8)
