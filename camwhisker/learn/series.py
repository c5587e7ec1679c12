"""Tables for learning: read and checked, targets encoded, normalised, cut into windows.

Each table is one continuous time series at a fixed rate, so a window (``window``
consecutive rows, its target the last row's) never spans two tables. Angle targets
(degrees) are encoded as (sin, cos), so the loss and the mean respect their periodicity;
they are decoded with atan2 back to degrees in (-180, 180].
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camwhisker.files.tables import read_columns

__all__ = ["LearnError", "Columns", "Series", "Normalisation", "read_series",
           "fit_normalisation", "encode_targets", "decode_targets", "window_ends",
           "gather_windows", "split_by_table", "split_in_time", "split_tables", "SPLITS",
           "segments"]  # fmt: skip

#: Share of the rows held out for validation when one table is given (its last rows).
VALIDATION_SHARE = 0.2


class LearnError(ValueError):
    """Bad input to learn or predict; the message names the file (and row, column or key)."""


@dataclass(frozen=True)
class Columns:
    """What a model reads and predicts: input, scalar target and angle target column names."""

    inputs: tuple[str, ...]
    targets: tuple[str, ...] = ()
    angle_targets: tuple[str, ...] = ()

    @property
    def all_targets(self) -> tuple[str, ...]:
        return self.targets + self.angle_targets

    @property
    def n_encoded(self) -> int:
        """Width of the encoded target: one per scalar, (sin, cos) per angle."""
        return len(self.targets) + 2 * len(self.angle_targets)


@dataclass
class Series:
    """One table: inputs shape (N, n_inputs), targets shape (N, n_targets) raw (degrees for
    angles), or None where only inputs were read (predict)."""

    path: Path
    inputs: np.ndarray
    targets: np.ndarray | None


@dataclass(frozen=True)
class Normalisation:
    """Per-column mean and std of the inputs and the scalar targets (angles are not scaled)."""

    input_mean: np.ndarray
    input_std: np.ndarray
    target_mean: np.ndarray
    target_std: np.ndarray

    def to_json(self) -> dict:
        return {k: [float(v) for v in getattr(self, k)] for k in
                ("input_mean", "input_std", "target_mean", "target_std")}  # fmt: skip

    @classmethod
    def from_json(cls, d: dict) -> Normalisation:
        return cls(*(np.asarray(d[k], float) for k in
                     ("input_mean", "input_std", "target_mean", "target_std")))  # fmt: skip


def read_series(path: str | Path, columns: Columns, window: int, with_targets: bool) -> Series:
    """Read one table's columns, every value finite and at least ``window`` rows.

    Raises
    ------
    LearnError
        A missing file or column, a non-number or non-finite cell (named by row and column),
        or fewer rows than the window.
    """
    path = Path(path)
    names = columns.inputs + (columns.all_targets if with_targets else ())
    try:
        cols = read_columns(path, names)
    except ValueError as exc:
        raise LearnError(str(exc)) from None
    for name in names:
        bad = np.flatnonzero(~np.isfinite(cols[name]))
        if bad.size:  # row 1 is the header
            raise LearnError(f"{path}: row {bad[0] + 2}, column {name}: not a finite number "
                             f"({bad.size} such row(s)); every input and target must be given")
    n = cols[names[0]].size if names else 0
    if n < window:
        raise LearnError(f"{path}: {n} rows, fewer than the window of {window}")
    x = np.stack([cols[c] for c in columns.inputs], axis=1)
    y = np.stack([cols[c] for c in columns.all_targets], axis=1) if with_targets else None
    return Series(path, x, y)


def fit_normalisation(series: list[Series], columns: Columns) -> Normalisation:
    """Mean and std of every input and scalar target over the training rows; a constant
    column gets std 1 (it carries nothing, and must not divide by zero)."""
    x = np.concatenate([s.inputs for s in series])
    y = np.concatenate([s.targets[:, : len(columns.targets)] for s in series])

    def std(a):
        s = a.std(axis=0)
        return np.where(s > 1e-12 * np.maximum(1.0, np.abs(a.mean(axis=0))), s, 1.0)

    return Normalisation(x.mean(axis=0), std(x), y.mean(axis=0), std(y))


def encode_targets(raw: np.ndarray, columns: Columns, norm: Normalisation) -> np.ndarray:
    """Raw targets shape (N, n_targets) -> encoded shape (N, n_encoded): scalars normalised,
    each angle (deg) as (sin, cos)."""
    k = len(columns.targets)
    scal = (raw[:, :k] - norm.target_mean) / norm.target_std
    ang = np.radians(raw[:, k:])
    return np.concatenate([scal, np.sin(ang), np.cos(ang)], axis=1).astype(np.float32)


def decode_targets(enc: np.ndarray, columns: Columns, norm: Normalisation) -> np.ndarray:
    """Encoded shape (N, n_encoded) -> raw shape (N, n_targets); angles by atan2 in degrees."""
    k, a = len(columns.targets), len(columns.angle_targets)
    enc = np.asarray(enc, float)
    scal = enc[:, :k] * norm.target_std + norm.target_mean
    ang = np.degrees(np.arctan2(enc[:, k : k + a], enc[:, k + a : k + 2 * a]))
    return np.concatenate([scal, ang], axis=1)


def window_ends(lengths: list[int], window: int) -> np.ndarray:
    """Row indices (into the tables concatenated) of every full window's last row."""
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    return np.concatenate([s + np.arange(window - 1, n) for s, n in zip(starts, lengths,
                                                                         strict=True)])


def gather_windows(x: np.ndarray, ends: np.ndarray, window: int) -> np.ndarray:
    """Windows shape (B, window, C) of rows ``x`` shape (N, C) ending at ``ends`` shape (B,)."""
    return x[ends[:, None] + np.arange(1 - window, 1)[None, :]]


def segments(usable: np.ndarray, min_rows: int = 1) -> list[slice]:
    """The maximal runs of consecutive True rows in ``usable`` shape (N,), each of at least
    ``min_rows`` rows (shorter ones hold no full window: dropped), in row order."""
    u = np.concatenate([[False], np.asarray(usable, bool), [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(u))
    return [slice(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)
            if b - a >= min_rows]


def split_by_table(series: list[Series], window: int) -> tuple[list[Series], list[Series]]:
    """(training, validation) tables: the last tables, together at least
    :data:`VALIDATION_SHARE` of the rows, held out (at least one kept for training); one
    table is cut in two contiguous parts (its last rows), so no window spans both."""
    if len(series) > 1:
        rows = np.cumsum([s.inputs.shape[0] for s in series[::-1]])
        n_val = int(np.searchsorted(rows, VALIDATION_SHARE * rows[-1])) + 1
        n_val = min(n_val, len(series) - 1)
        return series[:-n_val], series[-n_val:]
    s = series[0]
    n = s.inputs.shape[0]
    cut = int(round(n * (1.0 - VALIDATION_SHARE)))
    if cut < window or n - cut < window:
        raise LearnError(f"{s.path}: {n} rows are too few to hold out a validation part of "
                         f"{window} rows or more; give a second table")
    return ([Series(s.path, s.inputs[:cut], s.targets[:cut])],
            [Series(s.path, s.inputs[cut:], s.targets[cut:])])


def split_in_time(series: list[Series], window: int) -> tuple[list[Series], list[Series]]:
    """(training, validation) tables: each table's last :data:`VALIDATION_SHARE` of rows held
    out (its first rows kept), so every table's configuration is learned; a table too short
    to leave a window on both sides stays whole in training."""
    training, validation = [], []
    for s in series:
        n = s.inputs.shape[0]
        cut = int(round(n * (1.0 - VALIDATION_SHARE)))
        if cut < window or n - cut < window:
            training.append(s)
            continue
        training.append(Series(s.path, s.inputs[:cut], s.targets[:cut]))
        validation.append(Series(s.path, s.inputs[cut:], s.targets[cut:]))
    if not validation:
        raise LearnError(f"no table holds {2 * window} rows or more, too few to hold out a "
                         f"validation part of {window} rows after the training part "
                         f"({', '.join(str(s.path) for s in series[:3])})")
    return training, validation


#: The validation splits: name -> function (series, window) -> (training, validation).
SPLITS = {"time": split_in_time, "tables": split_by_table}


def split_tables(series: list[Series], window: int, how: str = "time"):
    """(training, validation) tables by the split ``how`` (:data:`SPLITS`)."""
    if how not in SPLITS:
        raise LearnError(f"unknown validation split {how!r} (known: {', '.join(SPLITS)})")
    return SPLITS[how](series, window)
