"""A model's predictions for a table: one row per input row, empty before the first window."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from camwhisker.files.tables import write_csv
from camwhisker.learn.modeldir import Model
from camwhisker.learn.series import read_series, segments, window_ends
from camwhisker.learn.train import predict_raw

__all__ = ["predict_rows", "predict_segments", "predict_table", "write_predictions"]


def predict_rows(model: Model, inputs: np.ndarray) -> np.ndarray:
    """Predicted targets shape (N, n_targets) for one continuous series of inputs shape
    (N, n_inputs), every value finite (raw units, angles in degrees); NaN in the first
    ``window - 1`` rows."""
    x = ((inputs - model.norm.input_mean) / model.norm.input_std).astype(np.float32)
    out = np.full((x.shape[0], len(model.columns.all_targets)), np.nan)
    if x.shape[0] < model.window:
        return out
    ends = window_ends([x.shape[0]], model.window)
    out[ends] = predict_raw(model.net, x, ends, model.window, model.columns, model.norm)
    return out


def predict_segments(model: Model, inputs: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """Like :func:`predict_rows` on rows with gaps: each run of consecutive ``usable`` rows
    shape (N,) is its own series (a window never spans a gap); NaN elsewhere and in each
    run's first ``window - 1`` rows. Rows not usable may hold anything (NaN)."""
    out = np.full((inputs.shape[0], len(model.columns.all_targets)), np.nan)
    for seg in segments(usable, model.window):
        out[seg] = predict_rows(model, inputs[seg])
    return out


def predict_table(model: Model, table: str | Path) -> np.ndarray:
    """Predicted targets shape (N, n_targets) for the table's N rows (raw units, angles in
    degrees); NaN in the first ``window - 1`` rows."""
    s = read_series(table, model.columns, model.window, with_targets=False)
    return predict_rows(model, s.inputs)


def write_predictions(model: Model, pred: np.ndarray, out: str | Path) -> None:
    """The predictions as CSV, one column per target (empty cells before the first window)."""
    write_csv(out, {name: pred[:, j] for j, name in enumerate(model.columns.all_targets)})
