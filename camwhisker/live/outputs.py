"""Where live results go: the signal table (CSV, flushed per row), JSON lines, UDP.

The CSV has batch's columns and batch's one row formatter
(:func:`camwhisker.batch.signal_row`), flushed row by row.

JSON lines and UDP datagrams carry one object per frame: frame, seq, t_s,
dz_mm, phi_deg, theta_deg, ok, latency_ms, note. Untrusted values are null.
"""

from __future__ import annotations

import csv
import json
import math
import socket

from camwhisker.batch import SIGNAL_COLUMNS, signal_row
from camwhisker.vision.tracker import FrameResult

__all__ = ["CsvSignalWriter", "result_message", "UdpSender", "DEFAULT_UDP_HOST"]

#: Results go to this machine only unless the user names another address.
DEFAULT_UDP_HOST = "127.0.0.1"


class CsvSignalWriter:
    """The signal table, written and flushed row by row (readable while it grows)."""

    def __init__(self, path):
        self.path = path
        self._fh = open(path, "w", newline="")  # noqa: SIM115 - closed in close()
        self._csv = csv.writer(self._fh)
        self._csv.writerow(SIGNAL_COLUMNS)
        self._fh.flush()
        self.rows = 0
        self.rows_ok = 0

    def write(self, t_s: float, r: FrameResult) -> None:
        self._csv.writerow(signal_row(t_s, r))
        self._fh.flush()
        self.rows += 1
        self.rows_ok += bool(r.ok)

    def close(self) -> None:
        if not self._fh.closed:
            self._fh.close()


def _num(x: float, digits: int) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), digits)


def result_message(seq: int, t_s: float, r: FrameResult, latency_ms: float) -> str:
    """One frame's result as compact JSON (a line on stdout, a UDP datagram)."""
    ok = bool(r.ok)
    return json.dumps({
        "frame": r.frame, "seq": seq, "t_s": _num(t_s, 6),
        "dz_mm": _num(r.dz_mm, 5) if ok else None,
        "phi_deg": _num(r.phi_deg, 5) if ok else None,
        "theta_deg": _num(r.theta_deg, 3) if ok else None,
        "ok": int(ok), "latency_ms": _num(latency_ms, 3), "note": r.reason,
    }, separators=(",", ":"))  # fmt: skip


class UdpSender:
    """One JSON datagram per frame to ``host:port`` (default this machine only)."""

    def __init__(self, port: int, host: str = DEFAULT_UDP_HOST):
        self.address = (host, int(port))
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sent = 0
        self.errors = 0

    def send(self, message: str) -> None:
        try:
            self._sock.sendto(message.encode(), self.address)
            self.sent += 1
        except OSError:  # nobody listening (ECONNREFUSED) or a full buffer: not fatal
            self.errors += 1

    def close(self) -> None:
        self._sock.close()
