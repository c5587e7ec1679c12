"""Our sensor's runs for the learned estimator: per frame phi, dz, theta and base travel -> r.

Inputs per frame (:data:`SENSOR_INPUTS`): phi and dz as the front end measured them, theta
as its cosine and sine (a direction: 179 and -179 deg are neighbours), and ``dx_mm``, the
base travel since first contact that the contact pipeline finds from the stage log (GM's
input). The target is the contact distance ``r_mm``; on calibration runs, the stage log's
known r at each frame's time after the clock alignment (what a user has, and what GM and
MF are calibrated on).

r has no value without contact, so a frame out of contact has no target and is not given
one: 0 or the whisker's length would be a distance nothing touches, which windows across
the onset would learn to blend with true ones. Contact itself stays the pipeline's call
(its onset starts dx); the learned estimate exists only within contact, like GM's and MF's.

A frame that cannot enter a window is cut, never filled: untrusted (ok = 0), theta
undefined (phi below the front end's floor), no travel (before first contact) and, when
training, no target or out of contact. Each run of consecutive usable frames is its own
table (:func:`~camwhisker.learn.series.segments`), so a window never spans a gap.
"""

from __future__ import annotations

import numpy as np

from camwhisker.contact.stage import StageLog
from camwhisker.learn.series import Columns, LearnError, Series, segments

__all__ = ["SENSOR_INPUTS", "TARGET", "sensor_columns", "frame_inputs", "input_matrix",
           "usable_rows", "run_tables", "log_r_mm", "learned_r_mm"]  # fmt: skip

SENSOR_INPUTS = ("phi_deg", "dz_mm", "theta_cos", "theta_sin", "dx_mm")
TARGET = "r_mm"


def sensor_columns(inputs: tuple[str, ...] = SENSOR_INPUTS) -> Columns:
    """The learn columns: some of :data:`SENSOR_INPUTS` (in that order) -> ``r_mm``."""
    unknown = [c for c in inputs if c not in SENSOR_INPUTS]
    if unknown or not inputs:
        raise LearnError(f"unknown sensor input(s) {', '.join(unknown) or '(none given)'} "
                         f"(known: {', '.join(SENSOR_INPUTS)})")
    return Columns(tuple(c for c in SENSOR_INPUTS if c in inputs), (TARGET,))


def frame_inputs(contact: dict, theta_deg) -> dict[str, np.ndarray]:
    """Every input of :data:`SENSOR_INPUTS` per frame, shape (N,), NaN where undefined.

    ``contact``: a contact table's columns (:func:`~camwhisker.contact.pipeline.contact_rows`:
    ``phi_deg``, ``dz_mm`` empty where not ok, ``dx_mm`` empty before first contact, ``ok``);
    ``theta_deg``: the signal table's theta of the same frames.
    """
    ok = np.asarray(contact["ok"]) > 0
    theta = np.radians(np.where(ok, np.asarray(theta_deg, float), np.nan))
    return {"phi_deg": np.asarray(contact["phi_deg"], float),
            "dz_mm": np.asarray(contact["dz_mm"], float),
            "theta_cos": np.cos(theta), "theta_sin": np.sin(theta),
            "dx_mm": np.asarray(contact["dx_mm"], float)}  # fmt: skip


def input_matrix(inputs: dict, columns: Columns) -> np.ndarray:
    """The model's input columns shape (N, n_inputs) from :func:`frame_inputs`' dict."""
    return np.stack([inputs[c] for c in columns.inputs], axis=1)


def usable_rows(x: np.ndarray, target=None, keep=None) -> np.ndarray:
    """Rows shape (N,) where every input (and the target, if given) is finite and ``keep``."""
    use = np.isfinite(x).all(axis=1)
    if target is not None:
        use &= np.isfinite(target)
    if keep is not None:
        use &= np.asarray(keep, bool)
    return use


def run_tables(inputs: dict, columns: Columns, name: str, window: int, target,
               keep=None) -> list[Series]:  # fmt: skip
    """One run's training tables: a :class:`~camwhisker.learn.series.Series` per run of
    consecutive usable rows (:func:`usable_rows`) of at least ``window`` rows, named
    ``name[start:stop]`` by its rows; ``target`` shape (N,) is r (mm)."""
    x = input_matrix(inputs, columns)
    r = np.asarray(target, float)
    use = usable_rows(x, r, keep)
    return [Series(f"{name}[{s.start}:{s.stop}]", x[s], r[s, None])
            for s in segments(use, window)]  # fmt: skip


def log_r_mm(log: StageLog, t_s, offset_s: float) -> np.ndarray:
    """The stage log's known r (mm) at camera times ``t_s`` (t_camera = t_stage + offset_s);
    NaN outside the log."""
    if log.r_mm is None:
        raise LearnError(f"{log.source}: no r_mm column: only calibration runs (known r) "
                         f"give training targets")  # fmt: skip
    t = np.asarray(t_s, float) - offset_s
    return np.interp(t, log.t_s, log.r_mm, left=np.nan, right=np.nan)


def learned_r_mm(model, contact: dict, theta_deg, source: str = "<model>") -> np.ndarray:
    """A sensor model's r (mm) per row of a contact table, shape (N,): each run of usable
    rows predicted on its own; NaN where an input is undefined (out of contact, untrusted)
    and in the first ``window - 1`` rows of each run.

    Raises
    ------
    LearnError
        ``source`` (the model directory) reads columns a contact table does not offer, or
        predicts something other than r_mm.
    """
    from camwhisker.learn.predict import predict_segments

    cols = model.columns
    other = [c for c in cols.inputs if c not in SENSOR_INPUTS]
    if other or cols.all_targets != (TARGET,):
        raise LearnError(f"{source}: reads {', '.join(cols.inputs)} -> "
                         f"{', '.join(cols.all_targets)}; a contact table offers "
                         f"{', '.join(SENSOR_INPUTS)} -> {TARGET} (python -m "
                         f"camwhisker.bench.learn sensor --out MODEL trains one)")  # fmt: skip
    x = input_matrix(frame_inputs(contact, theta_deg), cols)
    return predict_segments(model, x, usable_rows(x))[:, 0]
