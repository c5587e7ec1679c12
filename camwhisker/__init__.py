"""camwhisker: plate pose, contact distance and shape from a camera-based whisker sensor.

``import camwhisker as cw`` gives the Python API (:mod:`camwhisker.api`, docs/api.md):
``cw.track`` (video -> signal table), the readers ``cw.read_signals``,
``cw.read_stage_log``, ``cw.read_pose_log``, ``cw.read_force_log`` and
``cw.read_contacts`` (tables as pandas DataFrames), ``cw.calibrate``, ``cw.contacts``,
``cw.perceive``, ``cw.live_session`` and ``cw.live_rows`` (a live session's rows in Python,
for closed-loop control), and the sensor file (``cw.Sensor``, ``cw.load_sensor``) and calibration
(``cw.Calibration``, ``cw.read_calibration``, ``cw.write_calibration``).

The packages, in the order the data flows: :mod:`~camwhisker.files`,
:mod:`~camwhisker.sensor`, :mod:`~camwhisker.vision`, :mod:`~camwhisker.io`,
:mod:`~camwhisker.contact`, :mod:`~camwhisker.percept`, :mod:`~camwhisker.learn`,
:mod:`~camwhisker.calibration`, :mod:`~camwhisker.run`, :mod:`~camwhisker.live`; above
them :mod:`~camwhisker.sim` (simulators), :mod:`~camwhisker.bench` and
:mod:`~camwhisker.cli`, which the library never imports.
"""

__version__ = "0.1.0"

_API = ("Sensor", "load_sensor", "Calibration", "read_calibration", "write_calibration",
        "track", "read_signals", "read_stage_log", "read_pose_log", "read_force_log",
        "read_contacts",
        "calibrate", "contacts", "perceive", "live_session", "live_rows", "LiveRows")  # fmt: skip

__all__ = ["__version__", *_API]


def __getattr__(name: str):
    # The API loads on first use: `import camwhisker` alone stays light (the CLI, workers).
    if name in _API:
        from camwhisker import api

        return getattr(api, name)
    raise AttributeError(f"module 'camwhisker' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_API])
