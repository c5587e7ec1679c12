"""The package's TOML files (sensor, features, calibration): reading with one error style,
and values and comments written so that any text (a path with a tab or a newline) reads back."""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path

import numpy as np

__all__ = ["read_toml", "toml_value", "toml_comment", "toml_string"]


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
        return toml_string(v)
    if isinstance(v, list | tuple | np.ndarray):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


# TOML's short escapes; every other control character is written as \uXXXX.
_SHORT = {"\\": "\\\\", '"': '\\"', "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f",
          "\r": "\\r"}
# Control characters (TOML forbids them raw), the backslash and the quote; lone surrogates
# (undecodable bytes of a file name), which UTF-8 and TOML cannot hold.
_ESCAPED = re.compile(r'[\x00-\x1f\x7f"\\]|[\ud800-\udfff]')


def _escape(m: re.Match) -> str:
    c = m.group()
    if "\ud800" <= c <= "\udfff":
        return "\\uFFFD"  # the replacement character: TOML has no escape for a surrogate
    return _SHORT.get(c) or f"\\u{ord(c):04X}"


def toml_string(text: str) -> str:
    """``text`` as a TOML basic string: quotes, backslashes and control characters escaped."""
    return '"' + _ESCAPED.sub(_escape, text) + '"'


def toml_comment(text: str) -> str:
    """``# text`` on one line: control characters (a newline would end the comment and
    leave the rest to be read as TOML) written as escapes."""
    return "# " + re.sub(r"[\x00-\x08\x0a-\x1f\x7f]|[\ud800-\udfff]", _escape, text)
