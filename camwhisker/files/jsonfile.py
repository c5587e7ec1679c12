"""Strict JSON for every file and message the package writes: NaN and infinity as null.

JSON has no NaN: ``json.dumps`` writes a bare ``NaN`` by default, which strict
readers (JavaScript, jq, most languages' parsers) refuse. :func:`dumps`
turns every non-finite float into ``null``, numpy scalars and arrays into
plain numbers and lists, anything else (a path) into its text, and then
dumps with ``allow_nan=False``, so a value that slipped through is an error
here rather than a file nobody can read.
"""

from __future__ import annotations

import json
import math

import numpy as np

__all__ = ["plain", "dumps", "number"]


def plain(value):
    """``value`` as plain JSON types: dicts, lists, str, int, float (finite), bool, None."""
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return plain(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, str | int | bool):
        return value
    return str(value)


def number(x, digits: int | None = None) -> float | None:
    """A JSON number: ``x`` as a float (rounded to ``digits``), None where it is missing or
    not finite (JSON has no NaN)."""
    if x is None or not math.isfinite(x):
        return None
    return float(x) if digits is None else round(float(x), digits)


def dumps(value, **kwargs) -> str:
    """``json.dumps`` of :func:`plain` ``(value)``, strict (``allow_nan=False``)."""
    return json.dumps(plain(value), allow_nan=False, **kwargs)
