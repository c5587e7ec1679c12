"""The springs file (TOML, docs/sensor.md section 7.2): the suspension's stiffness for --springs.

Two optional tables say where k_z and k_phi come from. ``[design]`` holds the
spring model's inputs (:class:`camwhisker.sensor.springs.SpringDesign`; missing
keys take Table I's values), from which both stiffnesses are computed.
``[stiffness]`` holds values that replace the model's: fitted ones, with their
intervals, as :func:`write_springs` writes them after a calibration against a
force log (:mod:`camwhisker.calibration.springs_fit`). ``[provenance]`` says how the file was made.
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import fields
from pathlib import Path

from camwhisker import __version__
from camwhisker.calibration.springs_fit import SpringCalibration
from camwhisker.files.atomic import atomic_write_text
from camwhisker.files.tomlfile import read_toml, toml_value
from camwhisker.sensor.springs import (
    SpringDesign,
    SpringDesignError,
    Stiffness,
    suspension_stiffness,
)

__all__ = ["SpringsFileError", "read_springs", "read_design", "write_springs"]

_TABLES = ("provenance", "design", "stiffness")
# [stiffness] keys: the two values that replace the model's, then what the writer adds.
_VALUES = {"k_z_n_per_mm": "k_z", "k_phi_nmm_per_rad": "k_phi"}
_NOTES = ("k_z_source", "k_z_ci95_n_per_mm", "k_z_residual_sd_mN", "k_z_blocks", "k_z_note",
          "k_phi_source", "k_phi_ci95_nmm_per_rad", "k_phi_residual_sd_Nmm", "k_phi_blocks",
          "k_phi_note", "fz_rmse_mN", "mb_rmse_Nmm", "model_k_z_n_per_mm",
          "model_k_phi_nmm_per_rad")


class SpringsFileError(ValueError):
    """A springs file that cannot be used; the message names the file and key."""


def _design(doc: dict, path: Path) -> SpringDesign:
    table = doc.get("design", {})
    if not isinstance(table, dict):
        raise SpringsFileError(f"{path}: [design] must be a table")
    known = {f.name for f in fields(SpringDesign)}
    for key in table:
        if key not in known:
            raise SpringsFileError(f"{path}: [design] {key}: unknown key (known: "
                                   f"{', '.join(sorted(known))})")
    try:
        return SpringDesign(**table)
    except SpringDesignError as exc:
        raise SpringsFileError(f"{path}: [design] {exc}") from None


def _value(table: dict, key: str, path: Path) -> float:
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SpringsFileError(f"{path}: [stiffness] {key}: expected a number, got "
                               f"{type(value).__name__}")
    if not (math.isfinite(value) and value > 0):
        raise SpringsFileError(f"{path}: [stiffness] {key}: must be a positive number, "
                               f"got {value}")
    return float(value)


def _document(path: Path) -> dict:
    doc = read_toml(path, "springs file", SpringsFileError)
    if not doc:
        raise SpringsFileError(f"{path}: no table at all (an empty springs file); expected "
                               "[design] and/or [stiffness]")
    for table in doc:
        if table not in _TABLES:
            raise SpringsFileError(f"{path}: unknown table [{table}] (known: "
                                   f"{', '.join(_TABLES)})")
    return doc


def read_design(path: str | Path) -> SpringDesign:
    """A springs file's ``[design]`` (Table I's values for the keys it leaves out), the
    whole file checked as :func:`read_springs` checks it."""
    read_springs(path)
    path = Path(path)
    return _design(_document(path), path)


def _interval(table: dict, key: str, path: Path) -> tuple[float, float]:
    value = table[key]
    if (not isinstance(value, list) or len(value) != 2
            or any(isinstance(v, bool) or not isinstance(v, int | float) for v in value)):
        raise SpringsFileError(f"{path}: [stiffness] {key}: expected a list of two numbers "
                               "(the 95 % interval)")
    return float(value[0]), float(value[1])


def read_springs(path: str | Path) -> Stiffness:
    """The stiffness a springs file gives: the model of its ``[design]``, with the values
    of its ``[stiffness]`` in their place.

    Raises
    ------
    SpringsFileError
        Unreadable or empty file, bad TOML, an unknown table or key, a value that is
        not a positive number (each named).
    """
    path = Path(path)
    doc = _document(path)
    model = suspension_stiffness(_design(doc, path))
    given = doc.get("stiffness", {})
    if not isinstance(given, dict):
        raise SpringsFileError(f"{path}: [stiffness] must be a table")
    for key in given:
        if key not in _VALUES and key not in _NOTES:
            raise SpringsFileError(f"{path}: [stiffness] {key}: unknown key (known: "
                                   f"{', '.join((*_VALUES, *_NOTES))})")
    for key in ("k_z_ci95_n_per_mm", "k_phi_ci95_nmm_per_rad"):
        if key in given:
            _interval(given, key, path)  # checked even where its value is not given
    kz = _value(given, "k_z_n_per_mm", path) if "k_z_n_per_mm" in given else None
    kp = _value(given, "k_phi_nmm_per_rad", path) if "k_phi_nmm_per_rad" in given else None
    nan2 = (math.nan, math.nan)
    return Stiffness(
        k_z_n_per_mm=model.k_z_n_per_mm if kz is None else kz,
        k_phi_nmm_per_rad=model.k_phi_nmm_per_rad if kp is None else kp,
        source=str(path),
        k_z_ci95=(_interval(given, "k_z_ci95_n_per_mm", path)
                  if kz is not None and "k_z_ci95_n_per_mm" in given else nan2),
        k_phi_ci95=(_interval(given, "k_phi_ci95_nmm_per_rad", path)
                    if kp is not None and "k_phi_ci95_nmm_per_rad" in given else nan2),
    )


def _fit_lines(name: str, fit, unit: str, residual_unit: str) -> list[str]:
    if not fit.fitted:
        return [f"{name}_source = \"model\"", f"{name}_note = {toml_value(fit.why)}"]
    value_key = {"k_z": "k_z_n_per_mm", "k_phi": "k_phi_nmm_per_rad"}[name]
    return [f"{value_key} = {toml_value(fit.value)}", f"{name}_source = \"fitted\"",
            f"{name}_ci95_{unit} = {toml_value(list(fit.ci95))}",
            f"{name}_residual_sd_{residual_unit} = {toml_value(fit.residual_sd)}",
            f"{name}_blocks = {fit.blocks}"]


def write_springs(path: str | Path, calib: SpringCalibration, design: SpringDesign,
                  command: str = "") -> None:
    """Write a calibration as a springs file (atomically): fitted values replace the model's."""
    now = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    k = calib.stiffness(str(path))
    lines = [
        "# camwhisker springs file: the plate suspension's stiffness (docs/sensor.md "
        "section 7.2).",
        f"# k_z = {k.k_z_n_per_mm * 1e3:.4g} mN/mm ({'fitted' if calib.k_z.fitted else 'model'}),"
        f" k_phi = {k.k_phi_nmm_per_rad:.4g} N mm/rad "
        f"({'fitted' if calib.k_phi.fitted else 'model'}).",
        "",
        "[provenance]",
        'package = "camwhisker"',
        f"version = {toml_value(__version__)}",
        f"created_utc = {toml_value(now)}",
        f"command = {toml_value(command)}",
        "",
        "[design]",
        "# The spring model's inputs (Table I); its values stand where nothing was fitted.",
        *(f"{f.name} = {toml_value(getattr(design, f.name))}" for f in fields(design)),
        "",
        "[stiffness]",
        f"model_k_z_n_per_mm = {toml_value(calib.model.k_z_n_per_mm)}",
        f"model_k_phi_nmm_per_rad = {toml_value(calib.model.k_phi_nmm_per_rad)}",
        *_fit_lines("k_z", calib.k_z, "n_per_mm", "mN"),
        *_fit_lines("k_phi", calib.k_phi, "nmm_per_rad", "Nmm"),
        "# Per-frame RMSE of the force from the signal against the log (Fig. 6C).",
        f"fz_rmse_mN = {toml_value(calib.rmse['fz_mN'])}",
        f"mb_rmse_Nmm = {toml_value(calib.rmse['mb_Nmm'])}",
        "",
    ]
    for src, (offset, estimated, score) in zip(calib.sources, calib.offsets, strict=True):
        lines += ["[[provenance.runs]]", f"signals = {toml_value(src['signals'])}",
                  f"forces = {toml_value(src['forces'])}",
                  f"clock_offset_s = {toml_value(offset)}",
                  f"clock_offset_estimated = {toml_value(estimated)}",
                  f"clock_offset_score = {toml_value(score)}", ""]
    atomic_write_text(path, "\n".join(lines) + "\n")
