"""Reading the package's TOML files (sensor, features, calibration) with one error style."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np

__all__ = ["read_toml", "toml_value"]


def read_toml(path: str | Path, what: str, error: type[Exception]) -> dict:
    """The TOML document at ``path``; ``error`` naming the file and ``what`` it should
    hold where it cannot be read or is not TOML."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise error(f"{path}: cannot read {what} ({exc.strerror})") from exc
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: not valid TOML ({exc})") from exc


def toml_value(v) -> str:
    """A TOML value for a bool, number (nan and inf too), string or list of them."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | np.integer):
        return str(int(v))
    if isinstance(v, float | np.floating):
        v = float(v)
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list | tuple | np.ndarray):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")
