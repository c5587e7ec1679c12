"""Reading the package's TOML files (sensor, features, calibration) with one error style."""

from __future__ import annotations

import tomllib
from pathlib import Path

__all__ = ["read_toml"]


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
