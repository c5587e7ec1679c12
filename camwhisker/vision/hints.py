"""The features file (TOML): rough positions of the features in the rest frame.

Where detection cannot find a feature near where the sensor file's model puts
it (a build far from its file, pieces the model's outline misses), the user
reads rough positions off the rest check image once and passes them
(docs/sensor.md section 5.2). Detection then searches each hinted feature
around its hint (:func:`camwhisker.vision.detect.detect_features`).

The file has one table, ``[features]``, with any of the keys of
:class:`FeatureHints`, each a pixel position ``[u, v]``. An unknown table or
key, a value that is not two finite numbers, or a position outside the frame
raises :class:`FeatureHintsError` naming the file and the key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path

from camwhisker.files.tomlfile import read_toml

__all__ = ["FeatureHints", "FeatureHintsError", "load_feature_hints", "feature_hints_from_dict"]

#: The table the positions live in.
TABLE = "features"


class FeatureHintsError(ValueError):
    """A features file that cannot be used; the message names the file and key."""


@dataclass(frozen=True)
class FeatureHints:
    """Rough pixel positions (u, v) in the rest frame; None where not given.

    square_centre_px : the blue square's centre.
    cross_centre_px : the red cross's centre.
    tip_px : the centre of the magnifier tip's black end face.
    source : the file they were read from.
    """

    square_centre_px: tuple[float, float] | None = None
    cross_centre_px: tuple[float, float] | None = None
    tip_px: tuple[float, float] | None = None
    source: str = "<dict>"


_KEYS = tuple(f.name for f in fields(FeatureHints) if f.name != "source")


def load_feature_hints(path: str | Path, frame_size_px: tuple[int, int]) -> FeatureHints:
    """Read and validate a features file.

    Parameters
    ----------
    path : path
        The TOML file.
    frame_size_px : (int, int)
        The frame's width and height (the sensor file's ``width_px``, ``height_px``):
        every position must lie inside it.

    Raises
    ------
    FeatureHintsError
        The file is missing, is not TOML, or has an unknown or bad key.
    """
    data = read_toml(path, "features file", FeatureHintsError)
    return feature_hints_from_dict(data, frame_size_px, source=str(path))


def feature_hints_from_dict(
    data: dict, frame_size_px: tuple[int, int], source: str = "<dict>"
) -> FeatureHints:
    """Build validated :class:`FeatureHints` from parsed TOML tables."""
    unknown = set(data) - {TABLE}
    if unknown:
        raise FeatureHintsError(f"{source}: unknown table [{sorted(unknown)[0]}] (known: {TABLE})")
    if TABLE not in data:
        raise FeatureHintsError(f"{source}: no [{TABLE}] table")
    values = data[TABLE]
    if not isinstance(values, dict):
        raise FeatureHintsError(f"{source}: [{TABLE}] must be a table")
    kwargs = {}
    for key, value in values.items():
        where = f"{source}: [{TABLE}] {key}"
        if key not in _KEYS:
            raise FeatureHintsError(f"{where}: unknown key (known: {', '.join(_KEYS)})")
        kwargs[key] = _check_position(value, where, frame_size_px)
    return FeatureHints(**kwargs, source=source)


def _check_position(value, where: str, frame_size_px: tuple[int, int]) -> tuple[float, float]:
    if not isinstance(value, list) or len(value) != 2:
        raise FeatureHintsError(f"{where}: expected a pixel position [u, v], got {value!r}")
    uv = []
    for x in value:
        if isinstance(x, bool) or not isinstance(x, int | float):
            raise FeatureHintsError(f"{where}: expected numbers, got {type(x).__name__}")
        if not math.isfinite(x):
            raise FeatureHintsError(f"{where}: must be finite, got {x}")
        uv.append(float(x))
    width, height = frame_size_px
    # Pixel centres run from 0 to size - 1 (docs/sensor.md section 2).
    if not (0 <= uv[0] <= width - 1 and 0 <= uv[1] <= height - 1):
        raise FeatureHintsError(
            f"{where}: ({uv[0]:g}, {uv[1]:g}) lies outside the {width}x{height} px frame"
        )
    return uv[0], uv[1]
