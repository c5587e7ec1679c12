"""Where live results go besides the signal table: JSON lines and UDP.

The signal table is :class:`camwhisker.io.signals.SignalWriter`'s, flushed row by row.
JSON lines and UDP datagrams carry one object per frame: frame, seq, t_s,
dz_mm, phi_deg, theta_deg, ok, latency_ms, note. Untrusted values are null.
"""

from __future__ import annotations

import math
import socket

from camwhisker.files import jsonfile
from camwhisker.files.jsonfile import number
from camwhisker.io.signals import FORCE_COLUMNS
from camwhisker.vision.tracker import FrameResult

__all__ = ["result_fields", "result_message", "UdpSender", "DEFAULT_UDP_HOST"]

#: Results go to this machine only unless the user names another address.
DEFAULT_UDP_HOST = "127.0.0.1"


def result_fields(seq: int, t_s: float, r: FrameResult, latency_ms: float,
                  springs=None, extra: dict | None = None) -> dict:  # fmt: skip
    """One frame's result as plain Python values (floats, ints, str, None), rounded as the
    table's cells; with ``springs`` (a Stiffness) the forces too, as the table's columns;
    ``extra`` (the contact's fields, :mod:`camwhisker.live.contact`) last."""
    ok = bool(r.ok)
    msg = {
        "frame": int(r.frame), "seq": int(seq), "t_s": number(t_s, 6),
        "dz_mm": number(r.dz_mm, 5) if ok else None,
        "phi_deg": number(r.phi_deg, 5) if ok else None,
        "theta_deg": number(r.theta_deg, 3) if ok else None,
        "ok": int(ok), "latency_ms": number(latency_ms, 3), "note": r.reason,
    }  # fmt: skip
    if springs is not None:
        for key, value in zip(FORCE_COLUMNS, (springs.fz_mN(r.dz_mm), springs.mb_Nmm(r.phi_deg)),
                              strict=True):  # fmt: skip
            # The table's 5 significant digits, so a message and its row agree.
            msg[key] = float(f"{value:.5g}") if ok and math.isfinite(value) else None
    msg.update(extra or {})
    return msg


def result_message(seq: int, t_s: float, r: FrameResult, latency_ms: float,
                   springs=None, extra: dict | None = None) -> str:  # fmt: skip
    """:func:`result_fields` as compact JSON (a line on stdout, a UDP datagram)."""
    return jsonfile.dumps(result_fields(seq, t_s, r, latency_ms, springs, extra),
                          separators=(",", ":"))


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
