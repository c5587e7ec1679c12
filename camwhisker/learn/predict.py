"""A model's predictions for a table: one row per input row, empty before the first window."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from camwhisker.learn.modeldir import Model
from camwhisker.learn.series import decode_targets, read_series, window_ends
from camwhisker.learn.train import predict_encoded
from camwhisker.tables import write_csv

__all__ = ["predict_table", "write_predictions"]


def predict_table(model: Model, table: str | Path) -> np.ndarray:
    """Predicted targets shape (N, n_targets) for the table's N rows (raw units, angles in
    degrees); NaN in the first ``window - 1`` rows."""
    s = read_series(table, model.columns, model.window, with_targets=False)
    x = ((s.inputs - model.norm.input_mean) / model.norm.input_std).astype(np.float32)
    ends = window_ends([x.shape[0]], model.window)
    out = np.full((x.shape[0], len(model.columns.all_targets)), np.nan)
    out[ends] = decode_targets(predict_encoded(model.net, x, ends, model.window), model.columns,
                               model.norm)  # fmt: skip
    return out


def write_predictions(model: Model, pred: np.ndarray, out: str | Path) -> None:
    """The predictions as CSV, one column per target (empty cells before the first window)."""
    write_csv(out, {name: pred[:, j] for j, name in enumerate(model.columns.all_targets)})
