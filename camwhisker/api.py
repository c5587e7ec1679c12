"""The Python API: ``import camwhisker as cw``; tables as pandas DataFrames.

A session, as a notebook runs it (docs/api.md walks through it)::

    import camwhisker as cw

    signals = cw.track("run.mp4", sensor="sensor.toml")        # the table batch writes
    calib = cw.calibrate([("cal1.csv", "cal1.stage.csv"), ...], sensor="sensor.toml")
    table = cw.contacts(signals, cw.read_stage_log("run.stage.csv"), calib)
    obj = cw.perceive([table])

    for row in cw.live_rows(0, sensor="sensor.toml"):          # a live session's rows
        ...

Every function takes its data first and its options by keyword. ``contacts`` and
``perceive`` are named apart from the packages :mod:`camwhisker.contact` and
:mod:`camwhisker.percept`, which take those attribute names once imported. Paths and
DataFrames are interchangeable as inputs; a DataFrame is checked as the file would be.
"""

from __future__ import annotations

import contextlib
import csv
import io
import queue
import tempfile
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from camwhisker.contact.calibrate import CalibrationRun, read_calibration, write_calibration
from camwhisker.contact.pipeline import Calibration
from camwhisker.contact.stage import StageLog, stage_log_from_arrays
from camwhisker.contact.stage import read_stage_log as _read_stage_log
from camwhisker.files.tables import read_columns
from camwhisker.io.forcelog import read_force_log as _read_force_log
from camwhisker.io.signals import REQUIRED_COLUMNS, read_signal_table, signal_columns
from camwhisker.sensor.file import Sensor, load_sensor

if TYPE_CHECKING:
    import pandas as pd

    from camwhisker.live.loop import LiveReport, LiveSession
    from camwhisker.percept.percepts import Percept

__all__ = ["Sensor", "load_sensor", "Calibration", "read_calibration", "write_calibration",
           "track", "read_signals", "read_stage_log", "read_pose_log", "read_force_log",
           "read_contacts", "calibrate", "contacts", "perceive",
           "live_session", "live_rows", "LiveRows"]  # fmt: skip

def _pandas():
    import pandas as pd  # the core imports without pandas; the API needs it

    return pd


def _sensor(sensor: str | Path | Sensor | None) -> Sensor:
    return sensor if isinstance(sensor, Sensor) else load_sensor(sensor)


def track(video: str | Path, *, sensor: str | Path | Sensor | None = None, rest_frame: int = 0,
          fps: float | None = None, mode: str = "model", progress: bool = False
          ) -> pd.DataFrame:  # fmt: skip
    """The signal table of a video, as ``camwhisker batch`` writes it (docs/sensor.md section 6).

    Parameters
    ----------
    video : path
        A video file OpenCV can read, a folder of images (give ``fps``) or a recorded live
        session.
    sensor : path or Sensor, optional
        The build's sensor file; default: the nominal values (Table I).
    rest_frame : int
        The rest (reference) frame; earlier rows are untrusted (``ok`` = 0).
    fps : float, optional
        Frame rate of an image folder or of a video that states none.
    mode : {"model", "paper"}
        The exact camera model or the paper's eqs. 2-7.
    progress : bool
        A progress bar.

    Returns
    -------
    DataFrame, shape (frames, 12)
        One row per frame: frame, t_s, dz_mm, phi_deg, theta_deg, ok, sx_mm, sy_mm,
        phi_sigma_deg, n_corners, rms_px, note; the numbers batch prints, to its digits.
        Untrusted estimates are NaN.
    """
    from tqdm import tqdm

    from camwhisker.io.signals import signal_row, table_columns
    from camwhisker.io.sources import SessionSource, check_frame_size, open_source
    from camwhisker.vision import FrontEndOptions
    from camwhisker.vision.stream import stream

    sensor = _sensor(sensor)
    source = open_source(video, fps, None)
    check_frame_size(source, sensor)
    session = isinstance(source, SessionSource)
    rows = stream(source, sensor, FrontEndOptions(mode=mode), rest_frame, strict=not session)
    # Through CSV text, so the numbers are batch's to the digit.
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(table_columns())
    for frame, r in tqdm(rows, total=len(source) or None, unit="frame", disable=not progress):
        writer.writerow(signal_row(frame.t_s, r))
    buf.seek(0)
    return _pandas().read_csv(buf)


def read_signals(path: str | Path) -> pd.DataFrame:
    """A signal table (batch, live or replay), checked, as a DataFrame (empty cells NaN).

    Raises
    ------
    camwhisker.files.tables.TableError
        Missing file or column, a bad cell, t_s missing or not increasing; names file and row.
    """
    read_signal_table(path)
    return _pandas().read_csv(path)


def read_stage_log(path: str | Path) -> pd.DataFrame:
    """A stage log (docs/sensor.md section 7), checked, as a DataFrame.

    Raises
    ------
    camwhisker.contact.stage.StageLogError
        Names the file, row and column of what is wrong.
    """
    _read_stage_log(path)
    return _pandas().read_csv(path)


def read_force_log(path: str | Path) -> pd.DataFrame:
    """A force-torque log (docs/sensor.md section 7.1), checked, as a DataFrame."""
    _read_force_log(path)
    return _pandas().read_csv(path)


def read_pose_log(path: str | Path) -> pd.DataFrame:
    """A pose log (docs/sensor.md section 9), checked (row order, gaps, each quaternion's
    norm), as a DataFrame."""
    from camwhisker.io.poses import read_pose_log as _read

    _read(path)
    return _pandas().read_csv(path)


def read_contacts(path: str | Path) -> pd.DataFrame:
    """A contact table (``camwhisker contact``, docs/sensor.md section 7) as a DataFrame."""
    from camwhisker.contact.pipeline import CONTACT_COLUMNS

    read_columns(path, CONTACT_COLUMNS)  # a missing column or bad cell, named
    return _pandas().read_csv(path)


def _signals(table, what: str) -> dict:
    if isinstance(table, (str, Path)):
        return read_signal_table(table)
    cols = {c: np.asarray(table[c], float) for c in REQUIRED_COLUMNS if c in table}
    return signal_columns(cols, what)


def _stage(table, what: str) -> StageLog:
    if isinstance(table, StageLog):
        return table
    if isinstance(table, (str, Path)):
        return _read_stage_log(table)
    missing = [c for c in ("t_s", "x_mm") if c not in table]
    if missing:
        raise ValueError(f"{what}: no column {missing[0]}")
    opt = {c: np.asarray(table[c], float) if c in table else None for c in ("r_mm", "dz_mm")}
    return stage_log_from_arrays(table["t_s"], table["x_mm"], opt["r_mm"], source=what,
                                 dz_mm=opt["dz_mm"])  # fmt: skip


def calibrate(runs: Sequence[tuple], *, sensor: str | Path | Sensor | None = None,
              offsets_s: Sequence[float | None] | None = None) -> Calibration:
    """GM (eq. 8), sigma_GM and the MF table (eqs. 9-10) from calibration runs.

    Parameters
    ----------
    runs : sequence of (signals, stage)
        Each run's signal table and stage log (with ``r_mm``), as paths or DataFrames.
    sensor : path or Sensor, optional
        For the whisker's length; default: the nominal values.
    offsets_s : sequence of float or None, optional
        Known clock offsets (t_camera = t_stage + offset), one per run; default: estimated.

    Returns
    -------
    Calibration
        :func:`write_calibration` writes it as ``camwhisker calibrate`` does.
    """
    from camwhisker.contact.calibrate import calibrate as _calibrate

    sensor = _sensor(sensor)
    offsets_s = list(offsets_s) if offsets_s is not None else [None] * len(runs)
    if len(offsets_s) != len(runs):
        raise ValueError(f"give an offset per run or none ({len(runs)} runs, "
                         f"{len(offsets_s)} offsets)")  # fmt: skip
    cal_runs = []
    for k, ((signals, stage), offset) in enumerate(zip(runs, offsets_s, strict=True)):
        name = str(signals) if isinstance(signals, (str, Path)) else f"<run {k}>"
        cal_runs.append(CalibrationRun(_signals(signals, name), _stage(stage, f"{name} stage"),
                                       name, offset))  # fmt: skip
    return _calibrate(cal_runs, sensor.whisker.length_mm, sensor.source, "camwhisker.calibrate")[0]


def _pose_log(table, what: str, mount):
    """A pose log from a path or DataFrame with the pose columns; None for a stage log."""
    from camwhisker.io.poses import POSE_COLUMNS, PoseLog, pose_log_from_arrays, read_pose_log
    from camwhisker.io.poses import Mount as _Mount

    mount = _Mount.parse(mount) if isinstance(mount, str) else mount
    if isinstance(table, PoseLog):
        return table.mounted(mount)
    if isinstance(table, (str, Path)):
        from camwhisker.files.tables import read_header

        return read_pose_log(table, mount) if "qw" in read_header(table) else None
    if isinstance(table, StageLog) or "qw" not in table:
        return None
    missing = [c for c in POSE_COLUMNS if c not in table]
    if missing:
        raise ValueError(f"{what}: no column {missing[0]}")
    p = np.column_stack([np.asarray(table[c], float) for c in POSE_COLUMNS[1:4]])
    q = np.column_stack([np.asarray(table[c], float) for c in POSE_COLUMNS[4:]])
    return pose_log_from_arrays(np.asarray(table["t_s"], float), p, q, what).mounted(mount)


def contacts(signals, base, calib: str | Path | Calibration, *, offset_s: float | None = None,
             per: str = "frame", mount=None) -> pd.DataFrame:  # fmt: skip
    """Contact distance and shape per signal row (eqs. 8-12), as ``camwhisker contact``.

    Parameters
    ----------
    signals : path or DataFrame
        The run's signal table.
    base : path or DataFrame
        Its stage log, or its pose log (docs/sensor.md section 9: the columns qw ...): then
        the contact point and normal in the world frame are added (``px_mm`` ... ``nz``).
    calib : path or Calibration
    offset_s : float, optional
        Known clock offset; default: estimated.
    per : {"frame", "pause"}
        Estimates from each frame or from the medians of the frame's stage pause.
    mount : str or camwhisker.io.poses.Mount, optional
        ``X,Y,Z,QW,QX,QY,QZ``: where the pose log gives a carrier's pose.

    Returns
    -------
    DataFrame, shape (rows, columns of docs/sensor.md sections 7 and 9)
    """
    from camwhisker.contact.pipeline import contact_rows
    from camwhisker.contact.space import contact_rows_in_space

    calib = calib if isinstance(calib, Calibration) else read_calibration(calib)
    rows = _signals(signals, "<signals>")
    poses = _pose_log(base, "<poses>", mount)
    if poses is not None:
        cols, _, _ = contact_rows_in_space(rows, poses, calib, offset_s, mode=per)
    else:
        if mount is not None:
            raise ValueError("mount goes with a pose log")
        cols, _ = contact_rows(rows, _stage(base, "<stage>"), calib, offset_s, mode=per)
    return _pandas().DataFrame(cols)


def _in_space(table) -> bool:
    """Whether a contact table holds points in space (a path's header, a frame's columns)."""
    from camwhisker.files.tables import read_header

    return "px_mm" in (read_header(table) if isinstance(table, (str, Path)) else table)


def perceive(contacts: Sequence, *, poses: Sequence | None = None) -> Percept:
    """The object behind contact tables: wall, cylinder, box corner or nothing; for tables
    from a pose log (points in space), a plane, sphere, cylinder or nothing in their frame.

    Parameters
    ----------
    contacts : sequence of path or DataFrame
        Contact tables, of one run or several.
    poses : sequence of camwhisker.percept.surfels.Pose, optional
        Each table's stage pose in the object's frame; default: identity.

    Returns
    -------
    Percept
        ``best`` with ``params`` and ``intervals`` (95 %), ``runner_up``, ``evidence_ratio``.
    """
    from camwhisker.percept import solids
    from camwhisker.percept.percepts import perceive as _perceive
    from camwhisker.percept.surfels import (
        OPTIONAL_COLUMNS,
        Pose,
        merge,
        surfels_from_columns,
    )
    from camwhisker.percept.surfels import (
        REQUIRED_COLUMNS as SURFEL_COLUMNS,
    )

    if contacts and all(_in_space(c) for c in contacts):  # points in space: section 9's
        if poses is not None:
            raise ValueError("poses are for stage tables; tables in space carry their frame")
        names = (*solids.REQUIRED_COLUMNS, *solids.OPTIONAL_COLUMNS)
        tables = [read_columns(c, solids.REQUIRED_COLUMNS, solids.OPTIONAL_COLUMNS)
                  if isinstance(c, (str, Path))
                  else {k: np.asarray(c[k], float) for k in names if k in c}
                  for c in contacts]  # fmt: skip
        return solids.perceive_solid(solids.surfels_from_tables(tables))
    poses = list(poses) if poses is not None else [Pose()] * len(contacts)
    if len(poses) != len(contacts):
        raise ValueError(f"give one pose per contact table ({len(contacts)} tables, "
                         f"{len(poses)} poses)")  # fmt: skip
    parts = []
    for i, (table, pose) in enumerate(zip(contacts, poses, strict=True)):
        if isinstance(table, (str, Path)):
            cols, name = read_columns(table, SURFEL_COLUMNS, OPTIONAL_COLUMNS), str(table)
        else:
            missing = [c for c in SURFEL_COLUMNS if c not in table]
            if missing:
                raise ValueError(f"<contacts {i}>: no column {missing[0]}")
            cols = {c: np.asarray(table[c], float) for c in (*SURFEL_COLUMNS, *OPTIONAL_COLUMNS)
                    if c in table}  # fmt: skip
            name = f"<contacts {i}>"
        parts.append(surfels_from_columns(cols, pose, i, name))
    return _perceive(merge(parts))


def _live_session(source, sensor, out, mode: str, max_frames: int | None,
                  duration_s: float | None, fps: float | None, on_row,
                  calib) -> LiveSession:  # fmt: skip
    """A live session on a camera (an index, a node) or a file played at its frame rate."""
    from camwhisker.live.capture import SourceCapture, open_capture
    from camwhisker.live.loop import LiveConfig, LiveSession
    from camwhisker.vision import FrontEndOptions

    spec = str(source)
    rate = None
    if not isinstance(source, int) and Path(spec).exists() and not spec.startswith("/dev/"):
        probe = SourceCapture(spec, fps)  # the file's own rate paces it, as a camera would
        rate = probe.fps
        probe.release()
    elif not isinstance(source, int) and not spec.isdigit() and not spec.startswith("/dev/"):
        raise FileNotFoundError(f"{spec}: no such file or camera")
    path = str(calib) if isinstance(calib, (str, Path)) else None
    calib = read_calibration(calib) if path else calib  # before the capture opens
    capture = open_capture(spec, playback_fps=rate, fps=fps)
    config = LiveConfig(mode=mode, options=FrontEndOptions(), controls=False,
                        max_frames=max_frames, duration_s=duration_s, handle_signals=False,
                        record_rate_fps=rate or 30.0, on_row=on_row, calib=calib,
                        calib_path=path)  # fmt: skip
    return LiveSession(capture, _sensor(sensor), out, config)


def live_session(source, *, out: str | Path, on_row: Callable[[dict], object] | None = None,
         sensor: str | Path | Sensor | None = None, calib: str | Path | Calibration | None = None,
         mode: str = "latest",
         max_frames: int | None = None, duration_s: float | None = None,
         fps: float | None = None) -> LiveReport:  # fmt: skip
    """Run a live session to its end, as ``camwhisker live SOURCE --out OUT``, with a
    per-row callback (docs/api.md, "Live rows").

    Parameters
    ----------
    source : int, str or path
        A camera (index or node), or a video file or image folder played at its frame rate.
    out : path
        The signal table (``OUT.json`` beside it: the sidecar, with ``latency.on_row_ms``).
    on_row : callable, optional
        Called with each row as a dict (``LiveConfig.on_row``: the JSON line's fields) once
        it is written, in the session's thread; its time delays the next frame.
    sensor : path or Sensor, optional
        The build's sensor file; default: the nominal values.
    calib : path or Calibration, optional
        Adds the contact fields to every row (``contact``, belief, MF: docs/sensor.md).
    mode : {"latest", "every"}
        Drop stale frames (control) or process every frame.
    max_frames, duration_s : optional
        Stop after so many rows or seconds; default: the end of the file (a camera: Ctrl-C).
    fps : float, optional
        Frame rate of an image folder.

    Returns
    -------
    camwhisker.live.loop.LiveReport
        Rows, latencies (``on_row_ms`` included), drops, why it stopped, problems.

    Raises
    ------
    FileNotFoundError
        ``source`` names no file or camera.
    camwhisker.live.loop.RowCallbackError
        ``on_row`` raised: names the callback and frame; the table holds that frame's row.
    """
    return _live_session(source, sensor, out, mode, max_frames, duration_s, fps, on_row,
                         calib).run()


_END = object()


class _Feed:
    """What the session's thread shares with :class:`LiveRows` (not the iterator itself,
    so an iterator dropped after a ``break`` is collected, and its collection stops the
    session)."""

    def __init__(self, session: LiveSession, maxsize: int):
        self.session = session
        self.maxsize = maxsize
        self.queue: queue.Queue = queue.Queue(maxsize + 1)
        self.dropped = 0
        self.report: LiveReport | None = None
        self.error: BaseException | None = None

    def put(self, row) -> None:
        # In the session's thread, the only one that puts: it never waits on the consumer;
        # the oldest row makes room (the queue keeps one place more, for the end).
        while self.queue.qsize() >= self.maxsize:
            with contextlib.suppress(queue.Empty):
                self.queue.get_nowait()
                self.dropped += 1
        self.queue.put_nowait(row)

    def run(self) -> None:
        try:
            self.report = self.session.run()
        except BaseException as exc:  # handed to the consumer's thread
            self.error = exc
        finally:
            self.queue.put_nowait(_END)


class LiveRows:
    """The rows of a live session as they come (:func:`live_rows`): an iterator of dicts.

    ``dropped`` counts the rows dropped because the consumer lagged (the oldest go first);
    ``report`` is the session's LiveReport once it ended. ``close()`` (also on ``with``,
    and when the iterator is collected after a ``break``) stops the session and joins it.
    """

    def __init__(self, session: LiveSession, maxsize: int, tmp=None):
        self._feed = _Feed(session, maxsize)
        self._tmp = tmp  # a temporary table's folder, removed at the end
        self._done = False
        session.config.on_row = self._feed.put
        self._thread = threading.Thread(target=self._feed.run, name="camwhisker-live-rows",
                                        daemon=True)  # fmt: skip
        self._thread.start()

    @property
    def dropped(self) -> int:
        return self._feed.dropped

    @property
    def report(self) -> LiveReport | None:
        return self._feed.report

    def __iter__(self) -> Iterator[dict]:
        return self

    def __next__(self) -> dict:
        if self._done:
            raise StopIteration
        row = self._feed.queue.get()
        if row is _END:
            self._end()
            raise StopIteration
        return row

    def _end(self) -> None:
        self._done = True
        self._thread.join()
        if self._tmp is not None:
            self._tmp.cleanup()
        error, self._feed.error = self._feed.error, None
        if error is not None:
            raise error

    def close(self) -> None:
        """Stop the session (its outputs closed, as on Ctrl-C) and wait for it; raises the
        session's error if it failed and that was not raised yet."""
        if not self._done:
            self._feed.session.stop("closed")
            self._end()

    def __enter__(self) -> LiveRows:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()


def live_rows(source, *, sensor: str | Path | Sensor | None = None, out: str | Path | None = None,
              calib: str | Path | Calibration | None = None, mode: str = "latest",
              max_frames: int | None = None, duration_s: float | None = None,
              fps: float | None = None, maxsize: int = 256) -> LiveRows:  # fmt: skip
    """A live session's rows as an iterator, for closed-loop control in Python: the session
    runs in a background thread; each row (a dict, ``LiveConfig.on_row``'s) is yielded as it
    comes. Breaking out of the loop stops the session (docs/api.md, "Live rows").

    Parameters
    ----------
    source : int, str or path
        A camera (index or node), or a video file or image folder played at its frame rate.
    sensor : path or Sensor, optional
        The build's sensor file; default: the nominal values.
    out : path, optional
        Keep the signal table (and its sidecar) there; default: a temporary one, removed.
    calib, mode, max_frames, duration_s, fps
        As :func:`live_session`.
    maxsize : int
        Rows held for a consumer slower than the camera; beyond, the oldest are dropped
        and counted (``LiveRows.dropped``).

    Returns
    -------
    LiveRows
        Iterate it; ``dropped`` and, once ended, ``report`` (the LiveReport).

    Raises
    ------
    FileNotFoundError
        ``source`` names no file or camera.
    ValueError
        ``maxsize`` below 1.
    camwhisker.live.loop.RowCallbackError, or the session's own error
        Re-raised by the iteration (or ``close()``) in the consumer's thread.
    """
    if maxsize < 1:
        raise ValueError(f"maxsize must be at least 1, got {maxsize}")
    tmp = None
    if out is None:
        tmp = tempfile.TemporaryDirectory(prefix="camwhisker-live-")
        out = Path(tmp.name) / "live.csv"
    session = _live_session(source, sensor, out, mode, max_frames, duration_s, fps, None, calib)
    return LiveRows(session, maxsize, tmp)
