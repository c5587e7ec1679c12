"""The live view: a page in a browser showing what the sensor sees (``camwhisker live --view``).

:class:`LiveView` serves, with the standard library's threading HTTP server,
one page (``view.html``, plain JavaScript, nothing fetched from elsewhere):
the current frame drawn by :func:`camwhisker.run.overlay.annotate_frame` (tracked
corners, tip, the fitted model's outline, motion arrows at 10x), rolling plots
of phi, dz and theta (and the contact's fields; with base poses, the recent
contact points in W from above, x-y, and from the side, x-z, in mm), the frame
rate, drops and latency, and buttons that send
the session the commands its keys send (re-zero, re-detect, start/stop
recording).

The loop pays for none of it: :meth:`LiveView.publish` stores a reference to
the row (no copy, no drawing, no encoding), appends it to a bounded queue and
wakes the view's render thread. That thread moves the rows to the plots'
history and draws and encodes the newest frame, at most ``MAX_VIEW_FPS`` times
a second and only while a page asks for pictures: just after a row, so while
the loop waits for its next frame. Each connection has its own thread: a slow
or closed browser holds only that thread.

Endpoints: ``GET /`` the page; ``GET /frame.jpg?after=N`` the newest picture
(waits up to ``WAIT_S`` for one newer than frame N; its frame in the
``X-Frame`` header); ``GET /state?after=N`` JSON with the rows after frame N
and the figures; ``POST /command/NAME`` (``rezero``, ``redetect``,
``record``).

Who may use it: a request must be addressed to the view itself (``Host`` one of
its names with its port: 127.0.0.1, localhost, [::1], the address it is bound
to, and where bound to all interfaces this machine's name or any IP address),
which defeats DNS rebinding; a command also needs ``Origin`` (or, without it,
``Referer``) to be the view's own origin, so another page open in the browser
cannot send one. Off loopback (``--view-host`` not a loopback address) every
request also needs the session's random token (``?token=...``), printed once
at start as part of the page's URL; the page passes it on. Anything else is
403 (401 without the right token) and counted (:attr:`LiveView.rejected`, the
sidecar's ``view.rejected_requests``).
"""

from __future__ import annotations

import collections
import ipaddress
import json
import logging
import math
import secrets
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import cv2
import numpy as np

from camwhisker.files.jsonfile import number
from camwhisker.run.overlay import Placement, annotate_frame, is_rest_row, pose_vector
from camwhisker.sensor.model import PlateModel
from camwhisker.vision.stream import Frame
from camwhisker.vision.tracker import FrameResult

__all__ = ["DEFAULT_VIEW_HOST", "COMMANDS", "LiveView", "Published", "is_loopback"]

log = logging.getLogger(__name__)

#: The page is served to this machine only unless the user names another address.
DEFAULT_VIEW_HOST = "127.0.0.1"
#: Commands the page may send (LiveSession.command's names).
COMMANDS = ("rezero", "redetect", "record")
#: Most pictures drawn per second: enough to watch; each costs a few ms of a core
#: here and in the browser.
MAX_VIEW_FPS = 10.0
#: JPEG quality of the pictures: the overlay's 1 px lines stay sharp.
VIEW_JPEG_QUALITY = 80
#: Pictures are at most this wide (px), the page's width for them: half a 720p
#: frame, whose encoding, transfer and decoding in the browser cost ~1/4 as much.
VIEW_WIDTH_PX = 640
#: Nothing is drawn once no page has asked for a picture for this long (s).
CLIENT_IDLE_S = 2.0
#: Longest a request waits for a newer picture or row (s).
WAIT_S = 1.0
#: Rows kept for the plots (20 s at 30 frames/s), and at most this many wait for
#: the render thread (a stalled one never makes the loop's queue grow).
HISTORY_ROWS = 600
#: Rows over which the frame rate and the latency figures are taken.
STATS_ROWS = 90

_PAGE = Path(__file__).with_name("view.html")
#: The names every view answers to (with its port).
LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]")


def is_loopback(host: str) -> bool:
    """Whether ``host`` (a name or an address) is this machine only."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name.strip("[]"))
        return True
    except ValueError:
        return False


@dataclass(frozen=True)
class Published:
    """One row as the loop hands it over (no image: the queue of them holds none): its
    frame's index, time and event, its result, its capture-to-result latency, the
    drops so far and whether the session is recording (None: no recording configured)."""

    index: int
    t_s: float
    event: str
    result: FrameResult
    latency_ms: float
    dropped: int
    recording: bool | None
    contact: dict | None = None  # the row's contact fields (live --calib), as its message


#: The contact fields the plots show, in the row's last columns: the belief, the
#: contact distance (the fused one where the base is streamed in, else MF's) and Z.
CONTACT_PLOTS = (("contact_b",), ("r_hat_mm", "r_mf_mm"), ("z_score",))
#: With base poses, after them: the contact point in W, drawn from above and from the side.
POINT_FIELDS = ("px_mm", "py_mm", "pz_mm")


def _row_numbers(p: Published) -> list:
    r, ok = p.result, bool(p.result.ok)
    row = [p.index, number(p.t_s, 4), number(r.dz_mm, 5) if ok else None,
           number(r.phi_deg, 4) if ok else None, number(r.theta_deg, 2) if ok else None,
           int(ok), number(p.latency_ms, 2)]  # fmt: skip
    c = p.contact or {}
    for names in CONTACT_PLOTS:
        name = next((n for n in names if n in c), None)
        row.append(None if name is None or c[name] is None else number(c[name], 4))
    if POINT_FIELDS[0] in c:  # only sessions with poses: the other rows keep their length
        row += [None if c[n] is None else number(c[n], 4) for n in POINT_FIELDS]
    return row


class LiveView:
    """The view of one live session: an HTTP server and a render thread.

    Parameters
    ----------
    model : PlateModel
        The session's forward model (for the fitted outline).
    command : callable
        ``command(name)`` with a name of :data:`COMMANDS` (the session's
        :meth:`~camwhisker.live.loop.LiveSession.command`); a ValueError it
        raises is the page's error message.
    host, port : str, int
        Where to serve (port 0: any free port; :attr:`url` says which).

    Raises
    ------
    OSError
        The address cannot be bound (in use, not this machine's); the message names it.
    """

    def __init__(self, model: PlateModel, command: Callable[[str], None],
                 host: str = DEFAULT_VIEW_HOST, port: int = 0):  # fmt: skip
        self.model = model
        self.command = command
        self.page = _PAGE.read_bytes()
        try:
            self.server = ThreadingHTTPServer((host, port), _handler(self))
        except OSError as exc:
            raise OSError(f"--view {host}:{port}: cannot serve there: {exc.strerror}") from exc
        self.server.daemon_threads = True  # a hung browser never holds the process at exit
        self.host, self.port = self.server.server_address[:2]
        #: Required on every request off loopback (None on loopback).
        self.token = None if is_loopback(host) else secrets.token_urlsafe(24)
        self._names = _own_names(host)
        #: Requests refused: foreign Host, foreign origin, missing or wrong token.
        self.rejected = 0
        #: The newest row with its image (a reference the loop swaps), the rows not yet taken.
        self._latest: tuple[np.ndarray | None, Published] | None = None
        self._inbox: collections.deque[Published] = collections.deque(maxlen=HISTORY_ROWS)
        self._history: collections.deque[list] = collections.deque(maxlen=HISTORY_ROWS)
        self._events: list[dict] = []
        self._placement: Placement | None = None
        self._recording: bool | None = None
        #: The newest picture: (frame index, JPEG bytes).
        self._picture: tuple[int, bytes] | None = None
        self._asked_at = -math.inf
        self._changed = threading.Condition()
        self._new_row = threading.Event()
        self._stop = threading.Event()
        self._threads = [
            threading.Thread(target=self.server.serve_forever, args=(0.1,),
                             name="camwhisker-view-http", daemon=True),
            threading.Thread(target=self._render_loop, name="camwhisker-view-render",
                             daemon=True),
        ]  # fmt: skip
        self.pictures = 0
        self.requests = 0

    @property
    def stopped(self) -> bool:
        return self._stop.is_set()

    @property
    def url(self) -> str:
        """Where it serves (without the token: this goes in the sidecar)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    @property
    def page_url(self) -> str:
        """The page's URL to open, with the token where one is needed."""
        return self.url + (f"?token={self.token}" if self.token else "")

    def refusal(self, host: str | None, path: str, origin: str | None,
                command: bool) -> tuple[int, str] | None:  # fmt: skip
        """(status, reason) where a request must be refused, else None; ``host`` and
        ``origin`` are its Host and Origin (or Referer's origin) headers."""
        if not host or not self._own_host(host.lower()):
            return 403, "not addressed to this view (Host)"
        if self.token is not None:
            given = parse_qs(urlsplit(path).query).get("token", [""])[0]
            if not secrets.compare_digest(given.encode(), self.token.encode()):
                return 401, "the token is missing or wrong: open the URL printed at start"
        if command and (origin or "").lower() != f"http://{host.lower()}":
            return 403, "a command from another page (Origin)"
        return None

    def _own_host(self, host: str) -> bool:
        if host.endswith("]") or ":" not in host:  # no port: HTTP's default
            name, port = host, "80"
        else:
            name, _, port = host.rpartition(":")
        if port != str(self.port):
            return False
        return name in self._names or ("*" in self._names and _is_ip(name))

    def start(self) -> LiveView:
        for t in self._threads:
            t.start()
        return self

    def close(self) -> None:
        """Stop serving; open requests end within ``WAIT_S``."""
        self._stop.set()
        self._new_row.set()
        with self._changed:
            self._changed.notify_all()
        if self._threads[0].is_alive():
            self.server.shutdown()
        self.server.server_close()
        for t in self._threads:
            if t.is_alive():
                t.join()

    # ------------------------------------------------------ the loop's side
    def publish(self, frame: Frame, result: FrameResult, latency_ms: float, dropped: int,
                recording: bool | None = None, contact: dict | None = None) -> None:  # fmt: skip
        """Hand over a row (called by the loop): a reference stored, a bounded append,
        the render thread woken. ``contact``: the row's contact fields, if any."""
        p = Published(frame.index, frame.t_s, frame.event, result, latency_ms, dropped,
                      recording, contact)  # fmt: skip
        self._inbox.append(p)
        self._latest = (frame.image, p)
        self._new_row.set()

    # ---------------------------------------------------- the render thread
    def _render_loop(self) -> None:
        drawn, drawn_at = -1, -math.inf
        while True:
            self._new_row.wait()
            self._new_row.clear()
            if self._stop.is_set():
                return
            with self._changed:  # the requests read the history under this lock
                if self._take_rows():
                    self._changed.notify_all()
            image, p = self._latest
            now = time.monotonic()
            if (image is None or p.index == drawn or now - self._asked_at > CLIENT_IDLE_S
                    or now - drawn_at < 1.0 / MAX_VIEW_FPS):  # fmt: skip
                continue
            drawn, drawn_at = p.index, now
            try:
                data = self.render(image, p.result)
            except (ValueError, cv2.error) as exc:  # a frame it cannot draw: the next one
                log.warning("view: frame %d not drawn: %s", p.index, exc)
                continue
            with self._changed:
                self._picture = (p.index, data)
                self.pictures += 1
                self._changed.notify_all()

    def _take_rows(self) -> int:
        """Move the loop's rows into the history; the rest frames set the placement."""
        n = 0
        while True:
            try:
                p = self._inbox.popleft()
            except IndexError:
                return n
            n += 1
            r, event, index = p.result, p.event, p.index
            if is_rest_row(r, event, self._placement is not None):
                try:
                    self._placement = Placement.from_rest(self.model, r)
                except ValueError as exc:  # a rest row without every point: keep the last
                    log.warning("view: %s", exc)
            if event in ("rezero", "redetect"):
                self._events.append({"frame": index, "event": event, "ok": bool(r.ok)})
            if None not in (p.recording, self._recording) and p.recording != self._recording:
                what = "record-start" if p.recording else "record-stop"
                self._events.append({"frame": index, "event": what, "ok": True})
            self._recording = p.recording
            self._history.append(_row_numbers(p))

    def render(self, frame: np.ndarray, result: FrameResult) -> bytes:
        """A frame with the overlay of its result, at most ``VIEW_WIDTH_PX`` wide, as JPEG."""
        q = pose_vector(result) if self._placement is not None else None
        image = annotate_frame(frame, result, self._placement, q)
        height, width = image.shape[:2]
        if width > VIEW_WIDTH_PX:
            size = (VIEW_WIDTH_PX, round(height * VIEW_WIDTH_PX / width))
            image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, VIEW_JPEG_QUALITY])
        if not ok:  # pragma: no cover - JPEG encoding of a uint8 image does not fail
            raise OSError("JPEG encoding of the view failed")
        return data.tobytes()

    # ------------------------------------------------------ the page's side
    def picture_after(self, after: int) -> tuple[int, bytes] | None:
        """The newest picture, waiting up to ``WAIT_S`` for one newer than frame ``after``."""
        self._asked_at = time.monotonic()
        deadline = self._asked_at + WAIT_S
        with self._changed:
            while not self._stop.is_set():
                if self._picture is not None and self._picture[0] > after:
                    break
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._changed.wait(left)
            return self._picture

    def state_after(self, after: int) -> dict:
        """The rows after frame ``after`` (waiting up to ``WAIT_S`` for one) and the figures."""
        deadline = time.monotonic() + WAIT_S
        with self._changed:
            while not self._stop.is_set() and not (self._history and self._history[-1][0] > after):
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._changed.wait(left)
            rows = [row for row in self._history if row[0] > after]
            recent = list(self._history)[-STATS_ROWS:]
            events = list(self._events)
        latest = self._latest[1] if self._latest is not None else None
        return {"rows": rows, "events": events, **_figures(recent),
                "dropped": latest.dropped if latest else 0,
                "recording": latest.recording if latest else None}  # fmt: skip


def _own_names(host: str) -> set[str]:
    """The Host names a view bound to ``host`` answers to ("*": any IP address, for a
    view on every interface: an address typed in is no rebound name)."""
    names = set(LOOPBACK_NAMES) | {host.lower(), f"[{host.lower()}]"}
    if host in ("0.0.0.0", "::", ""):
        names |= {"*", socket.gethostname().lower(), socket.getfqdn().lower()}
    return names


def _figures(rows: list[list]) -> dict:
    """Frame rate (rows per second of their clock), latency p50 / p99 (ms) over ``rows``."""
    t = [row[1] for row in rows if row[1] is not None]
    lat = [row[6] for row in rows if row[6] is not None]
    fps = (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 and t[-1] > t[0] else None
    p50, p99 = np.percentile(lat, [50, 99]) if lat else (None, None)
    return {"fps": number(fps, 1) if fps else None, "latency_p50_ms": number(p50, 2),
            "latency_p99_ms": number(p99, 2)}


class _PageHandler(BaseHTTPRequestHandler):
    """The page's requests (see the module's notes); ``view`` is set per session."""

    view: LiveView

    protocol_version = "HTTP/1.1"  # keep-alive: one thread per page, not per request
    timeout = 10.0  # an idle connection's thread ends (the page asks every 0.2 s)

    def _closed(self) -> bool:
        """After the session: 503, and the connection closed."""
        if not self.view.stopped:
            return False
        self.close_connection = True
        self._json(503, {"error": "the session has ended"})
        return True

    def log_message(self, fmt, *args):  # the terminal is the session's
        log.debug("view: " + fmt, *args)

    def _send(self, status: int, body: bytes, kind: str, headers: dict | None = None):
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        for key, value in (headers or {}).items():
            self.send_header(key, value)
        self.end_headers()
        self.wfile.write(body)

    def _json(self, status: int, obj) -> None:
        self._send(status, json.dumps(obj, allow_nan=False).encode(), "application/json")

    def _refused(self, command: bool = False) -> bool:
        """Answer and count a request not from the view's own page (module notes)."""
        origin = self.headers.get("Origin")
        if origin is None and self.headers.get("Referer"):
            ref = urlsplit(self.headers["Referer"])
            origin = f"{ref.scheme}://{ref.netloc}"
        why = self.view.refusal(self.headers.get("Host"), self.path, origin, command)
        if why is None:
            return False
        if not self.view.rejected:
            log.warning("view: refused a request: %s", why[1])
        self.view.rejected += 1
        self.close_connection = True  # never read what a refused request sends
        self._json(why[0], {"error": why[1]})
        return True

    def _after(self, query: str) -> int:
        try:
            return int(parse_qs(query).get("after", ["-1"])[0])
        except ValueError:
            return -1

    def do_GET(self):  # noqa: N802 - the server's name for it
        self.view.requests += 1
        url = urlsplit(self.path)
        try:
            if self._refused() or self._closed():
                return
            if url.path in ("/", "/index.html"):
                self._send(200, self.view.page, "text/html; charset=utf-8")
            elif url.path == "/frame.jpg":
                picture = self.view.picture_after(self._after(url.query))
                if picture is None:
                    self._send(204, b"", "image/jpeg")
                else:
                    self._send(200, picture[1], "image/jpeg", {"X-Frame": str(picture[0])})
            elif url.path == "/state":
                self._json(200, self.view.state_after(self._after(url.query)))
            else:
                self._json(404, {"error": f"no page {url.path}"})
        except (BrokenPipeError, ConnectionResetError):  # the page went away
            pass

    def do_POST(self):  # noqa: N802
        self.view.requests += 1
        name = urlsplit(self.path).path.removeprefix("/command/")
        try:
            if self._refused(command=True) or self._closed():
                return
            if name not in COMMANDS:
                self._json(404, {"error": f"unknown command {name!r}"})
                return
            try:
                self.view.command(name)
            except ValueError as exc:  # e.g. recording without --record
                self._json(409, {"error": str(exc)})
                return
            self._json(200, {"command": name})
        except (BrokenPipeError, ConnectionResetError):
            pass


def _handler(view: LiveView) -> type[BaseHTTPRequestHandler]:
    return type("Handler", (_PageHandler,), {"view": view})
