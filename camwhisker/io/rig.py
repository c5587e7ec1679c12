"""Rig files: several sensors on one carrier (docs/sensor.md section 9), each with its mount.

A rig file (TOML, ``rig.toml`` in an experiment folder) lists the sensors a carrier holds:
a robot's flange, a bar, a mobile robot. The pose logs give the carrier's pose in W; each
sensor's mount is its pose S in the carrier's frame, so its pose in W is the carrier's
composed with its mount::

    # rig.toml: three whiskers on one bar; RUN.pose.csv is the bar's pose.
    [[sensor]]
    name = "low"                              # its recordings: the folder low/
    mount = [0.0, -30.0, 0.0, 1.0, 0.0, 0.0, 0.0]   # X,Y,Z (mm), QW,QX,QY,QZ
    sensor_file = "low.sensor.toml"           # optional; default: the folder's sensor.toml
    calibration = "low.calib.toml"            # optional; default: from low/'s calibration runs

    [[sensor]]
    name = "high"
    position_mm = [0.0, 30.0, 0.0]            # the mount as two keys, the same numbers
    quat = [1.0, 0.0, 0.0, 0.0]

A sensor's ``name`` is the folder of its recordings (letters, digits, ``_`` and ``-``);
``sensor_file`` and ``calibration`` are relative to the rig file's folder. How an
experiment folder lays out a rig's recordings: :mod:`camwhisker.run.rig_experiment`.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camwhisker.files.tomlfile import read_toml, toml_comment, toml_string, toml_value
from camwhisker.io.poses import QUAT_NORM_TOL, Mount

__all__ = ["RIG_NAME", "RigError", "RigSensor", "Rig", "read_rig", "dump_rig"]

#: An experiment folder's rig file.
RIG_NAME = "rig.toml"
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*")
_KEYS = {"name", "mount", "position_mm", "quat", "sensor_file", "calibration"}


class RigError(ValueError):
    """A rig file that cannot be used; the message names the file, the sensor and the key."""


@dataclass(frozen=True)
class RigSensor:
    """One sensor of a rig: its name, its mount, and its own sensor file and calibration
    file where the rig gives them (absolute or relative to the working folder)."""

    name: str
    mount: Mount
    sensor_file: Path | None = None
    calibration: Path | None = None

    def mount_record(self) -> dict:
        """The mount as JSON: ``position_mm`` and ``quat`` (scalar first)."""
        return {"position_mm": [float(v) for v in self.mount.position_mm],
                "quat": [float(v) for v in self.mount.quat]}  # fmt: skip


@dataclass(frozen=True)
class Rig:
    """A rig file read: its path and its sensors, in the file's order."""

    path: Path
    sensors: tuple[RigSensor, ...]

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.sensors]


def _numbers(where: str, key: str, value, n: int) -> list[float]:
    ok = isinstance(value, list) and len(value) == n and all(
        isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
        for v in value)  # fmt: skip
    if not ok:
        raise RigError(f"{where}, key {key}: expected a list of {n} finite numbers, got "
                       f"{value!r}")  # fmt: skip
    return [float(v) for v in value]


def _mount(where: str, entry: dict) -> Mount:
    """The mount from ``mount`` (seven numbers) or ``position_mm`` and ``quat``."""
    split = "position_mm" in entry or "quat" in entry
    if "mount" in entry and split:
        raise RigError(f"{where}: give the mount once: key mount, or keys position_mm and "
                       "quat, not both")  # fmt: skip
    if "mount" in entry:
        v, key = _numbers(where, "mount", entry["mount"], 7), "mount"
    elif split:
        for k in ("position_mm", "quat"):
            if k not in entry:
                raise RigError(f"{where}: key {k} missing (the mount is position_mm and quat)")
        v = _numbers(where, "position_mm", entry["position_mm"], 3) + \
            _numbers(where, "quat", entry["quat"], 4)  # fmt: skip
        key = "quat"
    else:
        raise RigError(f"{where}: key mount missing: the sensor's pose in the carrier's frame, "
                       "mount = [X, Y, Z, QW, QX, QY, QZ] (mm, then a unit quaternion, scalar "
                       "first), or position_mm and quat")  # fmt: skip
    norm = math.sqrt(sum(c * c for c in v[3:]))
    if abs(norm - 1.0) > QUAT_NORM_TOL:
        raise RigError(f"{where}, key {key}: the quaternion's norm is {norm:.6g}, not 1 (within "
                       f"{QUAT_NORM_TOL:g}; scalar first, docs/sensor.md section 9)")  # fmt: skip
    return Mount(np.array(v[:3]), np.array(v[3:]) / norm)


def _file(where: str, key: str, value, base: Path) -> Path | None:
    if value is None:
        return None
    if not isinstance(value, str) or not value:
        raise RigError(f"{where}, key {key}: expected a file name, got {value!r}")
    path = base / value
    if not path.is_file():
        raise RigError(f"{where}, key {key}: no such file {path}")
    return path


def _sensor(path: Path, k: int, entry) -> RigSensor:
    where = f"{path}: [[sensor]] {k}"
    if not isinstance(entry, dict):
        raise RigError(f"{where}: expected a table of keys")
    name = entry.get("name")
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise RigError(f"{where}, key name: expected the name of its recordings' folder "
                       f"(letters, digits, _ and -), got {name!r}")  # fmt: skip
    where = f"{path}: sensor {name}"
    unknown = sorted(set(entry) - _KEYS)
    if unknown:
        raise RigError(f"{where}: unknown key {unknown[0]} (known: {', '.join(sorted(_KEYS))})")
    return RigSensor(name, _mount(where, entry),
                     _file(where, "sensor_file", entry.get("sensor_file"), path.parent),
                     _file(where, "calibration", entry.get("calibration"), path.parent))


def read_rig(path: str | Path) -> Rig:
    """Read and check a rig file (module docstring).

    Raises
    ------
    RigError
        Not TOML, no ``[[sensor]]``, an unknown key, a name that is not a folder's or
        given twice, a missing mount, a mount that is not numbers, a quaternion whose
        norm is not 1 within :data:`~camwhisker.io.poses.QUAT_NORM_TOL`, a sensor or
        calibration file that does not exist. The message names the file, the sensor and
        the key.
    """
    path = Path(path)
    doc = read_toml(path, "a rig file", RigError)
    unknown = sorted(set(doc) - {"sensor"})
    if unknown:
        raise RigError(f"{path}: unknown key {unknown[0]} (a rig file holds [[sensor]] "
                       "tables)")  # fmt: skip
    entries = doc.get("sensor")
    if not isinstance(entries, list) or not entries:
        raise RigError(f"{path}: no sensor: expected one [[sensor]] table per sensor, each "
                       "with name and mount")  # fmt: skip
    sensors: list[RigSensor] = []
    for k, entry in enumerate(entries, start=1):
        s = _sensor(path, k, entry)
        if s.name in (o.name for o in sensors):
            raise RigError(f"{path}: sensor {s.name}, key name: given twice; each sensor has "
                           "its own name and folder")  # fmt: skip
        sensors.append(s)
    return Rig(path, tuple(sensors))


def dump_rig(sensors, comment: str = "") -> str:
    """A rig file's text: ``sensors`` as (name, mount's seven numbers, sensor file or None,
    calibration file or None)."""
    lines = [toml_comment(line) for line in comment.splitlines()]
    for name, mount, sensor_file, calibration in sensors:
        lines += ["", "[[sensor]]", f"name = {toml_string(name)}",
                  f"mount = {toml_value([float(v) for v in mount])}"]  # fmt: skip
        if sensor_file is not None:
            lines.append(f"sensor_file = {toml_string(str(sensor_file))}")
        if calibration is not None:
            lines.append(f"calibration = {toml_string(str(calibration))}")
    return "\n".join(lines).lstrip("\n") + "\n"
