"""The robot's base position, streamed in over UDP on its own thread, and its log.

One JSON datagram per position (docs/sensor.md, section 6.4)::

    {"t_s": 12345.678901, "x_mm": 12.3456}

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
a stage log for ``camwhisker contact --offset-s 0`` and ``camwhisker replay --base-log``.
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

__all__ = ["DEFAULT_BASE_HOST", "BaseReceiver", "parse_base_datagram", "base_log_path",
           "write_base_log", "read_base_log"]

log = logging.getLogger(__name__)

#: Positions are received from this machine only unless the user names another interface.
DEFAULT_BASE_HOST = "127.0.0.1"
#: How often the receiver looks at its stop flag while no datagram comes (s).
POLL_S = 0.1
#: Largest datagram read: a position is a few dozen bytes.
MAX_DATAGRAM = 4096


def parse_base_datagram(data: bytes) -> tuple[float, float]:
    """(t_s, x_mm) of one datagram; ValueError saying what is wrong."""
    try:
        msg = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        raise ValueError("not JSON") from None
    if not isinstance(msg, dict):
        raise ValueError("not a JSON object")
    out = []
    for key in ("t_s", "x_mm"):
        v = msg.get(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"key {key}: missing or not a finite number ({v!r})")
        out.append(float(v))
    return out[0], out[1]


class BaseReceiver:
    """Base positions from UDP datagrams (module docstring), on a daemon thread.

    Parameters
    ----------
    port : int
        0: one the system picks (``address`` says which).
    host : str
        The interface to listen on (default this machine only).
    clock : callable
        Monotonic seconds, for each datagram's arrival time.
    """

    def __init__(self, port: int, host: str = DEFAULT_BASE_HOST, clock=time.monotonic):
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.bind((host, int(port)))
        except OSError as exc:
            self._sock.close()
            raise OSError(f"--base-udp: cannot listen on {host}:{port} ({exc.strerror})") from None
        self._sock.settimeout(POLL_S)
        self.address = self._sock.getsockname()
        self._clock = clock
        self._lock = threading.Lock()
        self._samples: list[tuple[float, float, float]] = []  # (t_base_s, x_mm, arrived_s)
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
        self._sock.close()

    def _run(self) -> None:
        last_t = -math.inf
        while not self._stop.is_set():
            try:
                data = self._sock.recv(MAX_DATAGRAM)
            except TimeoutError:
                continue
            except OSError:  # closed under us: the session is ending
                return
            arrived = self._clock()
            try:
                t, x = parse_base_datagram(data)
                if not t > last_t:
                    raise ValueError("t_s not after the previous position's")
            except ValueError as exc:
                kind = str(exc).split(" (")[0]
                if kind not in self.rejected:
                    log.warning("base position datagram dropped: %s", exc)
                self.rejected[kind] = self.rejected.get(kind, 0) + 1
                continue
            last_t = t
            with self._lock:
                self._samples.append((t, x, arrived))
                self.received += 1

    def take(self) -> list[tuple[float, float, float]]:
        """The samples (t_base_s, x_mm, arrived_s) received since the last call."""
        with self._lock:
            new = self._samples[self._taken:]
            self._taken = len(self._samples)
        return new


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
