"""The robot's base position or pose, streamed in over UDP on its own thread, and its log.

One JSON datagram per position (docs/sensor.md, section 6.4)::

    {"t_s": 12345.678901, "x_mm": 12.3456}

or, for a base that moves in space (``live --base-poses``), per pose of the sensor (or
of its carrier, with ``--mount``) in the world frame (section 9; quaternion scalar
first, its norm 1 within QUAT_NORM_TOL)::

    {"t_s": 12345.678901, "x_mm": 1.0, "y_mm": 2.0, "z_mm": 3.0,
     "qw": 1.0, "qx": 0.0, "qy": 0.0, "qz": 0.0}

A session takes one kind, said when it starts: its table's columns are written
with the first row, before any datagram may have come. A datagram of the other
kind is dropped and counted like any bad one, its message naming the option.

``t_s`` is when the base was at ``x_mm``, on the sender's clock: by default
this machine's monotonic clock (CLOCK_MONOTONIC; Python's ``time.monotonic()``),
the clock the camera frames are stamped with, so a sender on this machine needs
no offset; from another clock, ``t_camera = t_base + offset_s`` with a given
offset. Other keys are ignored. A datagram that is not such an object, or whose
time is not after the previous one's, is counted and dropped (the first of each
kind is logged); the receiver never stops the session.

:class:`BaseReceiver` only receives and stamps (when each datagram arrived); the
session converts the times to the camera clock and hands them to the contact
estimate (:class:`~camwhisker.contact.online.BaseFeed`). The session writes what
it received as ``OUT.base.csv`` (``t_s, x_mm, received_s`` on the camera clock):
a stage log for ``camwhisker contact --offset-s 0`` and ``camwhisker replay --base-log``;
poses as ``OUT.pose.csv`` (section 9's pose log, with ``received_s``), for
``camwhisker contact --pose`` and ``camwhisker replay --pose-log`` (with the same
``--mount``: the log holds the poses as received).
"""

from __future__ import annotations

import json
import logging
import math
import socket
import threading
import time
from pathlib import Path

import numpy as np

from camwhisker.contact.stage import StageLogError
from camwhisker.files.atomic import atomic_path
from camwhisker.files.tables import read_log
from camwhisker.io.poses import POSE_COLUMNS, QUAT_NORM_TOL, PoseLogError, pose_log_from_arrays

__all__ = ["DEFAULT_BASE_HOST", "SampleReceiver", "BaseReceiver", "parse_base_datagram",
           "parse_pose_datagram", "check_quaternion",
           "base_log_path", "write_base_log", "read_base_log", "pose_log_path", "write_pose_log",
           "read_pose_log_samples"]

log = logging.getLogger(__name__)

#: Positions are received from this machine only unless the user names another interface.
DEFAULT_BASE_HOST = "127.0.0.1"
#: How often the receiver looks at its stop flag while no datagram comes (s).
POLL_S = 0.1
#: Largest datagram read: a position is a few dozen bytes.
MAX_DATAGRAM = 4096


#: A pose's keys after t_s (section 9's pose log columns).
POSE_KEYS = POSE_COLUMNS[1:]
#: Keys that only a pose has: a datagram with any of them is taken for a pose.
_POSE_ONLY = POSE_KEYS[1:]


def _object(data: bytes) -> dict:
    try:
        msg = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        raise ValueError("not JSON") from None
    if not isinstance(msg, dict):
        raise ValueError("not a JSON object")
    return msg


def _numbers(msg: dict, keys) -> list[float]:
    out = []
    for key in keys:
        v = msg.get(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"key {key}: missing or not a finite number ({v!r})")
        out.append(float(v))
    return out


def parse_base_datagram(data: bytes) -> tuple[float, float]:
    """(t_s, x_mm) of one datagram; ValueError saying what is wrong (a pose, with ``qw``,
    is refused: its x_mm alone is no travel)."""
    msg = _object(data)
    if "qw" in msg:
        raise ValueError("a pose where positions {t_s, x_mm} are expected (start live with "
                         "--base-poses)")
    t, x = _numbers(msg, ("t_s", "x_mm"))
    return t, x


def parse_pose_datagram(data: bytes) -> tuple[float, tuple[float, ...]]:
    """(t_s, (x_mm, y_mm, z_mm, qw, qx, qy, qz)) of one datagram, the quaternion as sent;
    ValueError saying what is wrong."""
    msg = _object(data)
    if "x_mm" in msg and not any(k in msg for k in _POSE_ONLY):
        raise ValueError("a position {t_s, x_mm} where poses are expected (the session "
                         "was started with --base-poses)")
    v = _numbers(msg, POSE_COLUMNS)
    return v[0], check_quaternion(v[1:], "keys qw-qz")


def check_quaternion(pose: list[float], where: str) -> tuple[float, ...]:
    """The pose's seven numbers (x_mm, y_mm, z_mm, qw, qx, qy, qz) as a tuple; ValueError
    naming ``where`` (the quaternion's keys or channels) if its norm is not 1."""
    norm = math.sqrt(sum(c * c for c in pose[3:]))
    if abs(norm - 1.0) > QUAT_NORM_TOL:
        raise ValueError(f"{where}: the quaternion's norm is not 1 within {QUAT_NORM_TOL:g} "
                         f"({norm:.6g}; scalar first)")
    return tuple(pose)


class SampleReceiver:
    """Base samples received on a daemon thread, checked, counted and kept for :meth:`take`.

    A subclass gives :meth:`_receive` (the next raw item, None after a poll with nothing,
    or :data:`CLOSED`) and :meth:`_parse` (its ``(t_s, x_mm or pose)``, ValueError saying
    what is wrong); ``where`` names the source in messages.

    Parameters
    ----------
    clock : callable
        Monotonic seconds, for each sample's arrival time.
    poses : bool
        Samples are poses (seven numbers), not positions.
    """

    where = "?"

    def __init__(self, clock=time.monotonic, poses: bool = False):
        self._clock = clock
        self.poses = poses
        self._lock = threading.Lock()
        self._samples: list[tuple] = []  # (t_base_s, x_mm or pose, arrived_s)
        self._taken = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="camwhisker-base", daemon=True)
        self.received = 0
        self.rejected: dict[str, int] = {}

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        self._close()

    def _close(self) -> None:
        """Release the source (after the thread has ended)."""

    def _receive(self):
        raise NotImplementedError

    def _parse(self, item) -> tuple[float, object]:
        raise NotImplementedError

    def _run(self) -> None:
        last_t = -math.inf
        while not self._stop.is_set():
            item = self._receive()
            if item is CLOSED:
                return
            if item is None:
                continue
            arrived = self._clock()
            try:
                t, x = self._parse(item)
                if not t > last_t:
                    raise ValueError("t_s not after the previous position's")
            except ValueError as exc:
                kind = str(exc).split(" (")[0]
                if kind not in self.rejected:
                    log.warning("base %s from %s dropped: %s",
                                "pose" if self.poses else "position", self.where, exc)
                self.rejected[kind] = self.rejected.get(kind, 0) + 1
                continue
            last_t = t
            with self._lock:
                self._samples.append((t, x, arrived))
                self.received += 1

    def take(self) -> list[tuple]:
        """The samples (t_base_s, x_mm or the pose's seven numbers, arrived_s) received
        since the last call."""
        with self._lock:
            new = self._samples[self._taken:]
            self._taken = len(self._samples)
        return new


#: :meth:`SampleReceiver._receive`'s answer once its source is closed under it.
CLOSED = object()


class BaseReceiver(SampleReceiver):
    """Base positions (or poses) from UDP datagrams (module docstring), on a daemon thread.

    Parameters
    ----------
    port : int
        0: one the system picks (``address`` says which).
    host : str
        The interface to listen on (default this machine only).
    clock : callable
        Monotonic seconds, for each datagram's arrival time.
    poses : bool
        Take poses (:func:`parse_pose_datagram`), not positions.
    """

    def __init__(self, port: int, host: str = DEFAULT_BASE_HOST, clock=time.monotonic,
                 poses: bool = False):  # fmt: skip
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.bind((host, int(port)))
        except OSError as exc:
            self._sock.close()
            raise OSError(f"--base-udp: cannot listen on {host}:{port} ({exc.strerror})") from None
        self._sock.settimeout(POLL_S)
        self.address = self._sock.getsockname()
        self.where = "{}:{}".format(*self.address)
        self._parse = parse_pose_datagram if poses else parse_base_datagram
        super().__init__(clock, poses)

    def _close(self) -> None:
        self._sock.close()

    def _receive(self):
        try:
            return self._sock.recv(MAX_DATAGRAM)
        except TimeoutError:
            return None
        except OSError:  # closed under us: the session is ending
            return CLOSED


def base_log_path(out_csv: str | Path) -> Path:
    """``OUT.base.csv`` beside ``OUT.csv``."""
    out = Path(out_csv)
    return out.with_name(out.stem + ".base.csv")


def write_base_log(path: str | Path, samples: list[tuple[float, float, float]]) -> Path:
    """The received positions (t_s, x_mm, received_s on the camera clock), atomically;
    written exactly (repr), so a replay reads back the numbers live used."""
    path = Path(path)
    lines = ["t_s,x_mm,received_s"] + [f"{t!r},{x!r},{r!r}" for t, x, r in samples]
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    return path


def read_base_log(path: str | Path, offset_s: float = 0.0) -> list[tuple[float, float, float]]:
    """A base log (:func:`write_base_log`, or any stage log: t_s, x_mm) as samples on the
    camera clock (t_s + offset_s); without ``received_s`` every sample counts as received
    from the start (each frame then sees them all, as the contact command does).

    Raises
    ------
    camwhisker.contact.stage.StageLogError
        Missing file or column, a bad cell (named by file, row and column).
    """
    cols, _ = read_log(path, ("t_s", "x_mm"), ("received_s",), "base log", StageLogError)
    t = cols["t_s"] + offset_s
    received = cols.get("received_s", np.full(t.shape, -math.inf))
    return [(float(a), float(b), float(c)) for a, b, c in zip(t, cols["x_mm"], received,
                                                             strict=True)]


def pose_log_path(out_csv: str | Path) -> Path:
    """``OUT.pose.csv`` beside ``OUT.csv``."""
    out = Path(out_csv)
    return out.with_name(out.stem + ".pose.csv")


def write_pose_log(path: str | Path, samples: list[tuple]) -> Path:
    """The received poses (t_s, the pose's seven numbers as sent, received_s; camera clock)
    as section 9's pose log with ``received_s``, atomically and exactly (repr)."""
    path = Path(path)
    lines = [",".join((*POSE_COLUMNS, "received_s"))]
    lines += [",".join(repr(float(v)) for v in (t, *pose, r)) for t, pose, r in samples]
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    return path


def read_pose_log_samples(path: str | Path, offset_s: float = 0.0) -> list[tuple]:
    """A pose log (:func:`write_pose_log`, or any of section 9) as samples (t_s + offset_s,
    the pose's seven numbers as written, received_s) on the camera clock; without
    ``received_s`` every sample counts as received from the start. Gaps are allowed (a
    live session's sender may pause).

    Raises
    ------
    camwhisker.io.poses.PoseLogError
        Missing file or column, a bad cell, times not increasing, a quaternion whose norm
        is not 1 (named by file, row and column).
    """
    cols, rows = read_log(path, POSE_COLUMNS, ("received_s",), "pose log", PoseLogError)
    p = np.column_stack([cols[k] for k in POSE_COLUMNS[1:4]])
    q = np.column_stack([cols[k] for k in POSE_COLUMNS[4:]])
    pose_log_from_arrays(cols["t_s"], p, q, str(path), rows, max_gap_s=math.inf)  # the checks
    t = cols["t_s"] + offset_s
    received = cols.get("received_s", np.full(t.shape, -math.inf))
    return [(float(t[i]), tuple(float(c) for c in (*p[i], *q[i])), float(received[i]))
            for i in range(t.size)]  # fmt: skip
