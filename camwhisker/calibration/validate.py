"""The paper's accuracy tests (Sec. III-A, Fig. 6 A/B): applied against measured phi or dz.

From each trial's signal table (docs/sensor.md section 6) and stage log
(section 7):

- **Test 1** steps a rigid whisker along x past a rigid contact at a known
  radial distance r (the log's ``r_mm``). The applied rotation follows from
  the geometry, tan(phi) = dx / r
  (:func:`rigid_phi_deg`, which the simulator shares), with
  dx the travel since first contact: given, or where the pause medians of phi
  extrapolate to zero (:func:`camwhisker.contact.stage.contact_onset_x`).
- **Test 2** applies known dz steps (the log's ``dz_mm``).

Per stage pause (:func:`camwhisker.contact.stage.detect_pauses`, with the clock offset
given or estimated from the tested signal) the applied value is the log's
median over the pause and the measured value the median of the trusted frames
in it (the paper: "all data were collected during pauses"), their standard
deviation the error bar. The RMSE is that of every trusted frame against its
pause's applied value, as the paper's 0.22 deg and 0.04 mm; the slope and
intercept are a least-squares line through the pause medians. Several trials
of one test pool their frames for the RMSE and bias and their pause medians for
the line (:func:`pooled`); each trial keeps its own clock offset.

References
----------
Sec. III-A and Fig. 6 A/B of the seed paper: "Identifying Contact Distance
Uncertainty in Whisker Sensing with Tapered, Flexible Whiskers".
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from camwhisker import __version__
from camwhisker.contact.stage import (
    MIN_PAUSE_FRAMES,
    MIN_PAUSE_S,
    PAUSE_TRIM_S,
    Pauses,
    StageLog,
    contact_onset_x,
    detect_pauses,
    estimate_offset,
    log_pause_medians,
    pause_frames,
)
from camwhisker.files import jsonfile
from camwhisker.files.atomic import atomic_write_text
from camwhisker.files.tables import write_csv
from camwhisker.sensor.file import Sensor, sensor_to_dict

if TYPE_CHECKING:
    from camwhisker.io.forcelog import ForceLog
    from camwhisker.sensor.springs import Stiffness

__all__ = ["TESTS", "ValidationError", "Validation", "validate", "pooled", "write_validation",
           "plot_validation", "force_check"]


@dataclass(frozen=True)
class _Test:
    quantity: str  # the signal table's column that the test moves
    symbol: str
    unit: str
    figure: str  # the paper's panel
    applied_from: str


#: The two tests: what each applies and measures.
TESTS = {
    1: _Test("phi_deg", "phi", "deg", "6A",
             "phi = atan(dx / r): a rigid whisker pivoting on its base through a contact r "
             "along its rest axis, dx the stage travel since first contact (paper Sec. III-A, "
             "test 1; r as in Fig. 1)"),
    2: _Test("dz_mm", "dz", "mm", "6B",
             "dz: the stage log's dz_mm, median over each pause (paper Sec. III-A, test 2)"),
}


class ValidationError(ValueError):
    """Input that cannot give a validation; the message names the file."""


@dataclass(frozen=True)
class Validation:
    """One trial of test 1 or 2: per-pause applied and measured values and their statistics.

    ``pauses`` holds arrays of shape (P,), one entry per stage pause: ``t_start_s``,
    ``t_end_s`` (camera clock), ``x_mm`` (the stage's median over the pause),
    ``applied``, ``measured`` (median), ``sd`` (of the frames), ``n_frames``,
    ``used`` (enough trusted frames and an applied value), and for test 1
    ``r_mm`` and ``dx_mm``. The statistics are
    over the used pauses: ``rmse`` and ``bias`` of the frames against their
    pause's applied value, ``rmse_medians`` of the medians, ``slope`` and
    ``intercept`` of medians against applied (NaN if applied never varies).
    """

    test: int
    pauses: dict
    rmse: float
    bias: float
    rmse_medians: float
    slope: float
    intercept: float
    n_frames: int
    offset_s: float
    offset_estimated: bool
    offset_score: float
    x_contact_mm: float
    x_contact_estimated: bool
    signals_source: str
    stage_source: str

    @property
    def spec(self) -> _Test:
        return TESTS[self.test]

    def statistics(self) -> dict:
        """The summary numbers, named with their unit."""
        u = self.spec.unit
        return {f"rmse_{u}": self.rmse, f"bias_{u}": self.bias,
                f"rmse_medians_{u}": self.rmse_medians, "slope": self.slope,
                f"intercept_{u}": self.intercept, "pauses_used": int(self.pauses["used"].sum()),
                "pauses_found": int(self.pauses["used"].size), "frames_used": self.n_frames}


def rigid_phi_deg(r_mm, dx_mm):
    """Rotation (deg) of a rigid whisker whose base has travelled dx past a contact at r.

    The whisker pivots on its base and passes through the contact point, which
    lies r along the rest axis and dx behind the base: tan(phi) = dx / r.
    Travel before contact (dx <= 0) gives exactly 0.

    Parameters
    ----------
    r_mm : array_like
        Radial contact distance along the rest axis (the paper's r, Fig. 1).
    dx_mm : array_like
        Base travel since first contact.

    Returns
    -------
    ndarray
        phi in [0, 90) deg.
    """
    dx = np.clip(np.asarray(dx_mm, dtype=float), 0.0, None)
    return np.degrees(np.arctan2(dx, np.asarray(r_mm, dtype=float)))


def _check_log(log: StageLog, test: int) -> Pauses:
    if test not in TESTS:
        raise ValidationError(f"test must be 1 or 2, got {test!r}")
    column = {1: "r_mm", 2: "dz_mm"}[test]
    if getattr(log, column) is None:
        raise ValidationError(f"{log.source}: test {test} needs the stage log's {column} column "
                              "(docs/sensor.md section 7)")
    pauses = detect_pauses(log)
    if pauses.t_start_s.size == 0:
        raise ValidationError(f"{log.source}: no pauses: the stage never stands still for "
                              f"{MIN_PAUSE_S:g} s")
    return pauses


def _clock(signals: dict, log: StageLog, measured, offset_s):
    """(offset_s, estimated, score): the given offset, else estimated from the tested signal."""
    if offset_s is not None:
        return float(offset_s), False, math.nan
    # The one signal that the test moves; the other holds only noise.
    offset, score = estimate_offset(log, signals["t_s"], measured)
    if not math.isfinite(offset):
        raise ValidationError(f"{log.source}: cannot estimate the clock offset (fewer than 2 "
                              "pauses); give it")
    return offset, True, score


def _applied_phi(log: StageLog, pauses: Pauses, x, median, x_contact_mm):
    """Test 1: (phi applied, extra columns, x_contact_mm, estimated) per pause at positions x."""
    sign = log.travel_sign
    estimated = x_contact_mm is None
    x0 = contact_onset_x(x, median, sign) if estimated else float(x_contact_mm)
    if not math.isfinite(x0):
        raise ValidationError(f"{log.source}: no contact seen (phi never reaches "
                              "the onset threshold in a pause); give the contact position")
    r = log_pause_medians(log, log.r_mm, pauses)
    dx = sign * (x - x0)
    return rigid_phi_deg(r, dx), {"r_mm": r, "dx_mm": dx}, x0, estimated


def _per_pause(stat, values, frames, enough) -> np.ndarray:
    """``stat`` of the values of each pause's frames where there are ``enough``, else NaN."""
    return np.array([stat(values[f]) if ok else np.nan
                     for f, ok in zip(frames, enough, strict=True)])


def _line(applied, median):
    """Least-squares slope and intercept of median on applied; NaN where applied never varies."""
    if np.ptp(applied) == 0.0:
        return math.nan, math.nan
    slope, intercept = np.polyfit(applied, median, 1)
    return float(slope), float(intercept)


def validate(signals: dict, log: StageLog, test: int, offset_s: float | None = None,
             x_contact_mm: float | None = None) -> Validation:
    """Applied against measured phi (test 1) or dz (test 2), pause by pause.

    Parameters
    ----------
    signals : dict
        A signal table as :func:`camwhisker.io.signals.read_signal_table` gives it.
    log : StageLog
        The trial's stage log, with ``r_mm`` (test 1) or ``dz_mm`` (test 2).
    test : {1, 2}
    offset_s : float, optional
        Known clock offset, t_camera = t_stage + offset_s; default: estimated.
    x_contact_mm : float, optional
        Test 1: stage position at first contact; default: from the pause medians.

    Raises
    ------
    ValidationError
        A missing column, no pauses, no offset or contact found, or fewer than
        two pauses with :data:`~camwhisker.contact.stage.MIN_PAUSE_FRAMES` trusted frames.
    """
    pauses = _check_log(log, test)
    spec = TESTS[test]
    t = np.asarray(signals["t_s"], float)
    measured = np.asarray(signals[spec.quantity], float)
    good = np.asarray(signals["ok"], bool) & np.isfinite(measured)
    offset, estimated, score = _clock(signals, log, np.where(good, measured, np.nan), offset_s)
    frames = pause_frames(t, good, pauses, offset)
    n = np.array([f.size for f in frames])
    enough = n >= MIN_PAUSE_FRAMES
    median = _per_pause(np.median, measured, frames, enough)
    sd = _per_pause(lambda v: np.std(v, ddof=1), measured, frames, enough)
    # The stage's position over each pause: a pause's first sample may still be
    # finishing the step (within the stationary tolerance).
    x = log_pause_medians(log, log.x_mm, pauses)
    extra, x0, x0_estimated = {}, math.nan, False
    if test == 1:
        applied, extra, x0, x0_estimated = _applied_phi(log, pauses, x, median, x_contact_mm)
    else:
        applied = log_pause_medians(log, log.dz_mm, pauses)
    used = enough & np.isfinite(applied)
    if used.sum() < 2:
        raise ValidationError(f"{signals.get('source', '<signals>')}: {int(used.sum())} of the "
                              f"{used.size} pauses of {log.source} hold {MIN_PAUSE_FRAMES} or "
                              "more trusted frames; need 2 (is the clock offset right?)")
    residual = np.concatenate([measured[frames[k]] - applied[k] for k in np.flatnonzero(used)])
    slope, intercept = _line(applied[used], median[used])
    table = {"t_start_s": pauses.t_start_s + offset, "t_end_s": pauses.t_end_s + offset,
             "x_mm": x, **extra, "applied": applied, "measured": median, "sd": sd,
             "n_frames": n, "used": used}
    return Validation(
        test=test, pauses=table, rmse=float(np.sqrt(np.mean(residual**2))),
        bias=float(np.mean(residual)),
        rmse_medians=float(np.sqrt(np.mean((median[used] - applied[used]) ** 2))),
        slope=slope, intercept=intercept, n_frames=int(residual.size), offset_s=offset,
        offset_estimated=estimated, offset_score=score, x_contact_mm=x0,
        x_contact_estimated=x0_estimated, signals_source=str(signals.get("source", "<signals>")),
        stage_source=log.source,
    )


def force_check(result: Validation, signals: dict, log: ForceLog, springs: Stiffness,
                offset_s: float | None = None) -> dict:
    """Fig. 6C: F_z from the signal (k_z times the pause's median dz) against the force log.

    Per used pause of a test-2 ``result``, the log's median over the pause (the
    same :data:`~camwhisker.contact.stage.PAUSE_TRIM_S` in from either end, on the camera
    clock: t_camera = t_force + offset_s, given or estimated as
    :func:`camwhisker.calibration.springs_fit.estimate_force_offset` does). Returns the RMSE over
    the pauses (mN), the clock and the per-pause values (``fz_log_mN``,
    ``fz_signal_mN``; NaN where a pause is not used).
    """
    from camwhisker.calibration.springs_fit import estimate_force_offset

    if result.test != 2:
        raise ValidationError(f"{log.source}: a force log checks test 2 (dz), not test "
                              f"{result.test}")
    estimated = offset_s is None
    if estimated:
        offset_s, _ = estimate_force_offset(signals, log)
    p = result.pauses
    tf = log.t_s + offset_s
    fz_log = np.full(p["used"].size, np.nan)
    for k in np.flatnonzero(p["used"]):
        inside = (tf >= p["t_start_s"][k] + PAUSE_TRIM_S) & (tf <= p["t_end_s"][k] - PAUSE_TRIM_S)
        if inside.any():
            fz_log[k] = np.median(log.fz_mN[inside])
    fz_signal = np.where(p["used"], springs.fz_mN(p["measured"]), np.nan)
    both = np.isfinite(fz_log) & np.isfinite(fz_signal)
    if not both.any():
        raise ValidationError(f"{log.source}: no pause of {result.signals_source} lies inside "
                              "the force log (is the clock offset right?)")
    rmse = float(np.sqrt(np.mean((fz_signal[both] - fz_log[both]) ** 2)))
    return {"fz_rmse_mN": rmse, "pauses": int(both.sum()), "force_offset_s": float(offset_s),
            "force_offset_estimated": estimated, "k_z_n_per_mm": springs.k_z_n_per_mm,
            "springs": springs.source, "forces": log.source, "fz_log_mN": fz_log,
            "fz_signal_mN": fz_signal}


def pooled(results: list[Validation]) -> dict:
    """The statistics of several trials of one test, named as
    :meth:`Validation.statistics`: RMSE and bias over every trial's frames, the
    line through every trial's pause medians, and each trial's RMSE."""
    if len({r.test for r in results}) != 1:
        raise ValidationError("trials of different tests cannot be pooled")
    first = results[0]
    if len(results) == 1:
        return first.statistics()
    u = first.spec.unit
    n = np.array([r.n_frames for r in results], float)
    rmse = np.array([r.rmse for r in results])
    applied = np.concatenate([r.pauses["applied"][r.pauses["used"]] for r in results])
    median = np.concatenate([r.pauses["measured"][r.pauses["used"]] for r in results])
    slope, intercept = _line(applied, median)
    return {f"rmse_{u}": float(np.sqrt(np.sum(n * rmse**2) / n.sum())),
            f"bias_{u}": float(np.sum(n * [r.bias for r in results]) / n.sum()),
            f"rmse_medians_{u}": float(np.sqrt(np.mean((median - applied) ** 2))),
            "slope": slope, f"intercept_{u}": intercept, "pauses_used": int(applied.size),
            "pauses_found": sum(int(r.pauses["used"].size) for r in results),
            "frames_used": int(n.sum()), "trials": len(results),
            f"rmse_per_trial_{u}": rmse.tolist()}  # fmt: skip


def _pause_columns(result: Validation, trial: int) -> dict:
    """The per-pause CSV's columns, named with the tested quantity and its unit."""
    p, s = result.pauses, result.spec
    cols = {"trial": np.full(p["x_mm"].size, trial), "pause": np.arange(p["x_mm"].size),
            "t_start_s": p["t_start_s"], "t_end_s": p["t_end_s"], "x_mm": p["x_mm"]}
    cols.update({k: p[k] for k in ("r_mm", "dx_mm") if k in p})
    cols[f"{s.symbol}_applied_{s.unit}"] = p["applied"]
    cols[f"{s.symbol}_measured_{s.unit}"] = p["measured"]
    cols[f"{s.symbol}_sd_{s.unit}"] = p["sd"]
    cols["n_frames"] = p["n_frames"]
    cols["used"] = p["used"].astype(int)
    return cols


def _trial_record(result: Validation) -> dict:
    """One trial's inputs, clock and contact position, and statistics."""
    return {
        "inputs": {"signals": result.signals_source, "stage": result.stage_source},
        "clock_offset_s": result.offset_s,
        "clock_offset_estimated": result.offset_estimated,
        "clock_offset_score": result.offset_score,
        "x_contact_mm": result.x_contact_mm,
        "x_contact_estimated": result.x_contact_estimated,
        "statistics": result.statistics(),
    }


def write_validation(results: list[Validation], out_dir: str | Path,
                     sensor: Sensor | None = None, command: str = "",
                     forces: list[dict] | None = None) -> dict:  # fmt: skip
    """Write ``test<N>_pauses.csv`` (every trial's pauses, numbered from 1),
    ``test<N>.json`` and the figure ``fig<6A|6B>.png``.

    The JSON says how the result was made: package version, command, time,
    sensor file, how the applied values were found, the constants of the pause
    detection, each trial's inputs, clock offset, contact position and
    statistics, and the statistics pooled over the trials (:func:`pooled`), and
    where ``forces`` (one :func:`force_check` per trial) are given, Fig. 6C's F_z
    RMSE per trial and over every trial's pauses.
    Returns the written paths by role (``pauses``, ``summary``, ``plot``).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stats = pooled(results)
    test, spec = results[0].test, results[0].spec
    paths = {"pauses": out / f"test{test}_pauses.csv",
             "summary": out / f"test{test}.json",
             "plot": out / f"fig{spec.figure.lower()}.png"}
    parts = [_pause_columns(r, k) for k, r in enumerate(results, start=1)]
    write_csv(paths["pauses"], {c: np.concatenate([p[c] for p in parts]) for c in parts[0]})
    plot_validation(results, paths["plot"], command or f"camwhisker validate, test {test}")
    record = {
        "camwhisker_version": __version__,
        "made_by": "camwhisker.calibration.validate.write_validation",
        "created_utc": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "command": command,
        "test": test,
        "quantity": spec.quantity,
        "applied_from": spec.applied_from,
        "sensor_file": None if sensor is None else sensor.source,
        "sensor": None if sensor is None else sensor_to_dict(sensor),
        "constants": {"MIN_PAUSE_S": MIN_PAUSE_S, "PAUSE_TRIM_S": PAUSE_TRIM_S,
                      "MIN_PAUSE_FRAMES": MIN_PAUSE_FRAMES},
        "statistics": stats,
        "trials": [_trial_record(r) for r in results],
        "files": {k: p.name for k, p in paths.items()},
    }
    if forces:
        diff = np.concatenate([f["fz_signal_mN"] - f["fz_log_mN"] for f in forces])
        diff = diff[np.isfinite(diff)]
        record["forces"] = {
            "fz_rmse_mN": float(np.sqrt(np.mean(diff**2))), "pauses": int(diff.size),
            "trials": [{k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in f.items()}
                       for f in forces]}  # fmt: skip
    atomic_write_text(paths["summary"], jsonfile.dumps(record, indent=2) + "\n")
    return paths


def plot_validation(results: list[Validation], path: str | Path, how: str = "") -> None:
    """Fig. 6 A/B: measured against applied per pause, sd error bars, one colour per
    trial, identity line, the pooled RMSE."""

    from camwhisker.files.figures import new_figure, save_figure

    spec, stats = results[0].spec, pooled(results)
    fig, ax = new_figure((5.2, 5.0))
    used = [r.pauses["used"] for r in results]
    values = np.concatenate([np.r_[r.pauses["applied"][u], r.pauses["measured"][u]]
                             for r, u in zip(results, used, strict=True)])  # fmt: skip
    lo, hi = float(values.min()), float(values.max())
    ax.plot([lo, hi], [lo, hi], "-", color="0.6", lw=1, label="measured = applied")
    for k, (r, u) in enumerate(zip(results, used, strict=True), start=1):
        label = "pause median, ±1 sd of its frames"
        if len(results) > 1:
            label = f"trial {k}: " + label
        ax.errorbar(r.pauses["applied"][u], r.pauses["measured"][u], yerr=r.pauses["sd"][u],
                    fmt="o", ms=4, capsize=3, color=f"C{(k - 1) % 10}", label=label)  # fmt: skip
    ax.set_xlabel(f"applied {spec.symbol} ({spec.unit})")
    ax.set_ylabel(f"measured {spec.symbol} ({spec.unit})")
    ax.set_aspect("equal", adjustable="datalim")
    trials = f"{len(results)} trials, " if len(results) > 1 else ""
    ax.set_title(f"Fig. {spec.figure}: test {results[0].test}, RMSE "
                 f"{stats[f'rmse_{spec.unit}']:.3g} {spec.unit}\nslope {stats['slope']:.4f}, "
                 f"{trials}{stats['pauses_used']} pauses, {stats['frames_used']} frames",
                 fontsize=10)  # fmt: skip
    ax.legend(loc="upper left", fontsize=8)
    save_figure(fig, path, how or f"Fig. {spec.figure} (test {results[0].test})")
