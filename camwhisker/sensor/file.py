"""The sensor file (TOML): typed, validated, with defaults from the paper's Table I.

The file has three tables, ``[camera]``, ``[plate]`` and ``[whisker]``; units are
in the key names (see docs/sensor.md section 5). Missing keys take the defaults
below. An unknown table or key, a value of the wrong type, a non-finite or
non-positive length, or an impossible geometry raises :class:`SensorFileError`
naming the file and the key.

Default intrinsics come from the paper's angles of view read as half angles
(Table I: 26.95 deg over 640 px, 16.26 deg over 360 px), which gives
fx / fy = 1.02, the paper's v/u corrector mu (eq. 5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from functools import cached_property
from pathlib import Path

import numpy as np

from camwhisker.files.tomlfile import read_toml, toml_comment, toml_value

__all__ = [
    "CameraConfig",
    "PlateConfig",
    "WhiskerConfig",
    "Sensor",
    "SensorFileError",
    "load_sensor",
    "sensor_from_dict",
    "sensor_to_dict",
    "dump_sensor",
    "OPTIONAL_PLATE_KEYS",
    "MAX_ROTATION_DEG",
    "MAX_ROD_TILT_DEG",
]

# Table I's angles of view, read as half angles (module docstring).
_FX_DEFAULT = 640.0 / math.tan(math.radians(26.95))
_FY_DEFAULT = 360.0 / math.tan(math.radians(16.26))


class SensorFileError(ValueError):
    """A sensor file that cannot be used; the message names the file and key."""


@dataclass(frozen=True)
class CameraConfig:
    """Pinhole intrinsics (pixels) and OpenCV distortion (k1, k2, p1, p2, k3)."""

    width_px: int = 1280
    height_px: int = 720
    fx_px: float = round(_FX_DEFAULT, 2)
    fy_px: float = round(_FY_DEFAULT, 2)
    cx_px: float = 639.5
    cy_px: float = 359.5
    distortion: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)

    @cached_property
    def matrix(self) -> np.ndarray:
        """Camera matrix K, shape (3, 3)."""
        return np.array(
            [[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]]
        )

    @cached_property
    def dist_coeffs(self) -> np.ndarray:
        """Distortion coefficients as OpenCV wants them, shape (5,)."""
        return np.asarray(self.distortion, dtype=float)

    @property
    def has_distortion(self) -> bool:
        return any(c != 0.0 for c in self.distortion)


@dataclass(frozen=True)
class PlateConfig:
    """Geometry of the plate and its tracking features, in millimetres.

    Plate frame: origin at the centre of rotation, z toward the whisker (away
    from the camera), x and y parallel to the image's u and v at rest.
    """

    z_i_mm: float = 25.0
    h_r_mm: float = 7.5
    square_side_mm: float = 5.0
    square_offset_mm: float = 1.5
    cross_span_mm: float = 4.0
    cross_arm_mm: float = 1.2
    cross_offset_mm: float = 1.5
    rod_diameter_mm: float = 1.0
    # Optional keys of a real build (docs/sensor.md section 5.1); zero is nominal.
    tip_offset_x_mm: float = 0.0
    tip_offset_y_mm: float = 0.0
    square_shift_x_mm: float = 0.0
    square_shift_y_mm: float = 0.0
    square_rotation_deg: float = 0.0
    cross_shift_x_mm: float = 0.0
    cross_shift_y_mm: float = 0.0
    cross_rotation_deg: float = 0.0


@dataclass(frozen=True)
class WhiskerConfig:
    length_mm: float = 150.0


@dataclass(frozen=True)
class Sensor:
    camera: CameraConfig = field(default_factory=CameraConfig)
    plate: PlateConfig = field(default_factory=PlateConfig)
    whisker: WhiskerConfig = field(default_factory=WhiskerConfig)
    source: str = "<defaults>"

    def replace(self, **tables: dict) -> Sensor:
        """A copy with some keys changed, e.g. ``replace(camera={"cx_px": 600.0})``.

        The result is validated like a file.
        """
        data = sensor_to_dict(self)
        for table, values in tables.items():
            data.setdefault(table, {}).update(values)
        return sensor_from_dict(data, source=f"{self.source} (modified)")


#: [plate] keys that a nominal file leaves out: a build's in-plane misplacements
#: and the tip's lateral offset. They are written only where they are not zero.
OPTIONAL_PLATE_KEYS = (
    "tip_offset_x_mm",
    "tip_offset_y_mm",
    "square_shift_x_mm",
    "square_shift_y_mm",
    "square_rotation_deg",
    "cross_shift_x_mm",
    "cross_shift_y_mm",
    "cross_rotation_deg",
)
#: Largest in-plane rotation of a glued feature; beyond it the corners' directions
#: from the centre would no longer identify them.
MAX_ROTATION_DEG = 10.0
#: Largest tilt of the rod off the plate's normal, set by the tip's lateral offset.
MAX_ROD_TILT_DEG = 10.0

_TABLES = {"camera": CameraConfig, "plate": PlateConfig, "whisker": WhiskerConfig}


def load_sensor(path: str | Path | None = None) -> Sensor:
    """Read and validate a sensor file; ``None`` gives the defaults.

    Raises
    ------
    SensorFileError
        The file is missing, empty, is not TOML, or has an unknown or bad key.
    """
    if path is None:
        return Sensor()
    data = read_toml(path, "sensor file", SensorFileError)
    if not data:  # a failed copy, most likely: defaults a user did not ask for
        raise SensorFileError(f"{path}: no table at all (an empty sensor file); for the "
                              "defaults leave --sensor out")
    return sensor_from_dict(data, source=str(path))


def sensor_from_dict(data: dict, source: str = "<dict>") -> Sensor:
    """Build a validated :class:`Sensor` from parsed TOML tables."""
    unknown = set(data) - set(_TABLES)
    if unknown:
        raise SensorFileError(
            f"{source}: unknown table [{sorted(unknown)[0]}] (known: {', '.join(_TABLES)})"
        )
    parts = {}
    for table, cls in _TABLES.items():
        values = data.get(table, {})
        if not isinstance(values, dict):
            raise SensorFileError(f"{source}: [{table}] must be a table")
        parts[table] = _build_table(cls, table, values, source)
    sensor = Sensor(**parts, source=source)
    _check_geometry(sensor)
    return sensor


def sensor_to_dict(sensor: Sensor) -> dict:
    """The resolved configuration as plain TOML-able tables (for sidecars)."""
    out = {}
    for table in _TABLES:
        cfg = getattr(sensor, table)
        out[table] = {
            f.name: list(v) if isinstance(v := getattr(cfg, f.name), tuple) else v
            for f in fields(cfg)
            if not (table == "plate" and f.name in OPTIONAL_PLATE_KEYS and _is_zero(cfg, f.name))
        }
    return out


def _is_zero(cfg, key: str) -> bool:
    return getattr(cfg, key) == 0.0


def _build_table(cls, table: str, values: dict, source: str):
    known = {f.name: f for f in fields(cls)}
    kwargs = {}
    for key, value in values.items():
        where = f"{source}: [{table}] {key}"
        if key not in known:
            raise SensorFileError(f"{where}: unknown key (known: {', '.join(known)})")
        default = getattr(cls, key)
        if isinstance(default, tuple):
            kwargs[key] = _check_distortion(value, where, len(default))
        elif isinstance(default, int):
            kwargs[key] = _check_int(value, where)
        else:
            kwargs[key] = _check_float(value, where)
    return cls(**kwargs)


def _check_float(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SensorFileError(f"{where}: expected a number, got {type(value).__name__}")
    value = float(value)
    if not math.isfinite(value):
        raise SensorFileError(f"{where}: must be finite, got {value}")
    return value


def _check_int(value, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise SensorFileError(f"{where}: expected an integer, got {type(value).__name__}")
    return value


def _check_distortion(value, where: str, n: int) -> tuple[float, ...]:
    if not isinstance(value, list) or len(value) != n:
        raise SensorFileError(f"{where}: expected a list of {n} numbers (k1 k2 p1 p2 k3)")
    return tuple(_check_float(v, f"{where}[{i}]") for i, v in enumerate(value))


def _check_geometry(sensor: Sensor) -> None:
    src = sensor.source
    positive = {
        "camera": ["width_px", "height_px", "fx_px", "fy_px"],
        "plate": [
            f.name
            for f in fields(PlateConfig)
            if f.name != "square_offset_mm" and f.name not in OPTIONAL_PLATE_KEYS
        ],
        "whisker": ["length_mm"],
    }
    for table, keys in positive.items():
        cfg = getattr(sensor, table)
        for key in keys:
            if getattr(cfg, key) <= 0:
                raise SensorFileError(
                    f"{src}: [{table}] {key}: must be positive, got {getattr(cfg, key)}"
                )
    cam, plate = sensor.camera, sensor.plate
    if not (0 <= cam.cx_px <= cam.width_px - 1):
        raise SensorFileError(f"{src}: [camera] cx_px: {cam.cx_px} lies outside the image")
    if not (0 <= cam.cy_px <= cam.height_px - 1):
        raise SensorFileError(f"{src}: [camera] cy_px: {cam.cy_px} lies outside the image")
    if plate.square_offset_mm < 0:
        raise SensorFileError(f"{src}: [plate] square_offset_mm: must be >= 0")
    if plate.z_i_mm <= plate.h_r_mm:
        raise SensorFileError(
            f"{src}: [plate] z_i_mm: must exceed h_r_mm "
            f"({plate.z_i_mm} <= {plate.h_r_mm}): the magnifier tip would touch the lens"
        )
    if plate.cross_arm_mm >= plate.cross_span_mm:
        raise SensorFileError(f"{src}: [plate] cross_arm_mm: must be less than cross_span_mm")
    if plate.h_r_mm <= plate.cross_offset_mm:
        raise SensorFileError(
            f"{src}: [plate] h_r_mm: the rod must reach beyond the cross (h_r_mm > cross_offset_mm)"
        )
    _check_placement(sensor)


def _check_placement(sensor: Sensor) -> None:
    """The optional keys: misplacements small enough to leave each feature identifiable."""
    src, plate = sensor.source, sensor.plate
    limits = {
        "square_shift_x_mm": (plate.square_side_mm / 4, "a quarter of square_side_mm"),
        "square_shift_y_mm": (plate.square_side_mm / 4, "a quarter of square_side_mm"),
        "cross_shift_x_mm": (plate.cross_span_mm / 4, "a quarter of cross_span_mm"),
        "cross_shift_y_mm": (plate.cross_span_mm / 4, "a quarter of cross_span_mm"),
        "square_rotation_deg": (MAX_ROTATION_DEG, "the largest rotation"),
        "cross_rotation_deg": (MAX_ROTATION_DEG, "the largest rotation"),
    }
    for key, (limit, why) in limits.items():
        value = getattr(plate, key)
        if abs(value) > limit:
            raise SensorFileError(
                f"{src}: [plate] {key}: must lie within +-{limit:g} ({why}), got {value}"
            )
    offset = math.hypot(plate.tip_offset_x_mm, plate.tip_offset_y_mm)
    tilt_deg = math.degrees(math.atan2(offset, plate.h_r_mm - plate.cross_offset_mm))
    if tilt_deg > MAX_ROD_TILT_DEG:
        key = (
            "tip_offset_x_mm"
            if abs(plate.tip_offset_x_mm) >= abs(plate.tip_offset_y_mm)
            else ("tip_offset_y_mm")
        )
        raise SensorFileError(
            f"{src}: [plate] {key}: tilts the rod by {tilt_deg:.1f} deg, "
            f"more than {MAX_ROD_TILT_DEG:g} deg off the plate's normal"
        )


def dump_sensor(sensor: Sensor) -> str:
    """The resolved configuration as sensor-file TOML text (loads back to an equal Sensor)."""
    lines = [toml_comment(f"camwhisker sensor file (resolved from {sensor.source})")]
    for table, values in sensor_to_dict(sensor).items():
        lines.append(f"\n[{table}]")
        for key, value in values.items():
            if isinstance(value, list):
                value = "[" + ", ".join(repr(float(v)) for v in value) + "]"
            else:
                value = toml_value(value)
            lines.append(f"{key} = {value}")
    return "\n".join(lines) + "\n"
