"""The live loop: grabbed frames -> the streaming core -> CSV, JSON lines, UDP, recording.

:class:`LiveSession` feeds the grabbed frames, with the live events (re-zero,
re-detect, a gap where no frame came), to :func:`camwhisker.vision.stream.stream`
and sends each row to the outputs. It runs the grabber thread, takes commands
(``r`` re-zero, ``d`` re-detect, ``s`` start/stop recording, ``q`` quit) from the
terminal, from the browser view (:mod:`camwhisker.live.view`) or from
:meth:`LiveSession.command`, stops cleanly on Ctrl-C and SIGTERM, and writes
the sidecar (settings, grabber counts, latency, the rest references and their
mismatch checks; a mismatch is logged as a warning).

:func:`reprocess_session` drives the same generator over a recorded session
(:class:`~camwhisker.io.sources.SessionSource`): the live table again, row for
row. With an MCAP file (``--mcap``), both also write each row as ROS 2 messages
(:class:`~camwhisker.io.bag.BagStream`, docs/robots.md; live through a thread of its own,
:class:`~camwhisker.io.bag.BagThread`) with the frame's JPEG bytes; a
live session also to Lab Streaming Layer (``--lsl``, :mod:`camwhisker.live.lsl`), and takes
its base from LSL (``--base-lsl``) as from UDP.
:class:`LiveProcessor` hands the generator one frame at a time, for a
caller that times each frame.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import gc
import logging
import math
import os
import queue
import select
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from camwhisker.files.atomic import atomic_path, sync_file
from camwhisker.io.bag import BagStream, BagThread
from camwhisker.io.signals import (
    SignalWriter,
    sidecar,
    sidecar_path,
    signal_row,
    table_columns,
    write_sidecar,
    write_signals,
)
from camwhisker.io.sources import SessionSource, SourceError, check_frame_size
from camwhisker.live.base import (
    BaseReceiver,
    base_log_path,
    pose_log_path,
    write_base_log,
    write_pose_log,
)
from camwhisker.live.capture import describe
from camwhisker.live.contact import RowContact
from camwhisker.live.grabber import BACKOFF_S, MAX_RECONNECTS, Grabbed, Grabber
from camwhisker.live.lsl import LslBaseReceiver, LslError, LslOutlet
from camwhisker.live.outputs import DEFAULT_UDP_HOST, UdpSender, result_fields, result_message
from camwhisker.live.record import (
    JPEG_QUALITY,
    MjpgRoundTrip,
    SessionRecorder,
    decode_keeping_jpeg,
    decode_only,
    encode_jpeg,
    recorded_jpegs,
)
from camwhisker.live.view import DEFAULT_VIEW_HOST, LiveView
from camwhisker.sensor.file import Sensor
from camwhisker.sensor.model import PlateModel
from camwhisker.vision.stream import Frame, stream
from camwhisker.vision.tracker import FrameResult, FrontEndOptions

__all__ = ["LiveProcessor", "reprocess_session", "LiveConfig", "LiveSession", "LiveReport",
           "RowCallbackError", "latency_summary", "run_live"]  # fmt: skip

log = logging.getLogger(__name__)

#: How often the loop looks at its stop flag while no frame comes (s): the
#: longest a stop waits; the wait itself blocks, it does not spin.
POLL_S = 0.1
#: A camera whose measured rate differs from the rate it reports by more than this
#: share is named in the problems (drivers report the requested rate, not the real one,
#: e.g. under low light with auto exposure the C310 halves its rate).
FPS_MISMATCH = 0.1
#: Keys read from a terminal.
KEYS = {"r": "rezero", "d": "redetect", "s": "record", "q": "quit"}


class RowCallbackError(RuntimeError):
    """The ``on_row`` callback raised; the session stopped, its outputs closed. The
    callback's own exception is the ``__cause__``."""


class LiveProcessor:
    """The live stream (:func:`~camwhisker.vision.stream.stream`) fed one frame per call."""

    def __init__(self, sensor: Sensor, options: FrontEndOptions | None = None):
        self._frame: Frame | None = None
        self._rows = stream(self._frames(), sensor, options, strict=False, warm_up=True)

    def _frames(self) -> Iterator[Frame]:
        while True:
            yield self._frame

    def process(self, index: int, image: np.ndarray | None, event: str = "") -> FrameResult:
        """The row for frame ``index`` (``image`` None: a gap)."""
        self._frame = Frame(index, math.nan, image, event)
        return next(self._rows)[1]


def reprocess_session(video: str | Path, sensor: Sensor, out_csv: str | Path,
                      options: FrontEndOptions | None = None, springs=None,
                      contact=None, mcap: str | Path | None = None) -> Path:  # fmt: skip
    """Process a recorded session again: the same rows as the live table (with the
    forces where ``springs``, a Stiffness, is given, and the contact's fields where
    ``contact`` is: a function of the recording's frame period (s) that gives the
    :class:`~camwhisker.live.contact.RowContact`, fed the logged base positions).

    With ``mcap``, the rows also go there as ROS 2 messages (:class:`BagStream`), each
    frame's image as the JPEG bytes stored in the recording. The table and the bag are
    written whole or not at all: an interrupted replay leaves both as they were.

    Raises
    ------
    FileNotFoundError
        No video or no timestamps file.
    camwhisker.io.sources.SourceError
        The video cannot be decoded, or holds fewer frames than the timestamps list.
    camwhisker.io.bag.BagError
        With ``mcap``: the MCAP packages not installed, or a row's t_s not a time.
    """
    source = SessionSource(video)
    check_frame_size(source, sensor)
    rest_log: list = []
    rows = stream(source, sensor, options, strict=False, rest_log=rest_log)
    out_csv = Path(out_csv)
    if contact is None and mcap is None:
        with atomic_path(out_csv) as tmp:
            write_signals(tmp, ((frame.t_s, r) for frame, r in rows), springs)
        return out_csv
    contact = contact(1.0 / source.fps) if contact is not None else None
    extra = contact.fields if contact is not None else ()
    with contextlib.ExitStack() as stack:
        tmp = stack.enter_context(atomic_path(out_csv))
        writer = stack.enter_context(SignalWriter(tmp, springs=springs, extra=extra))
        bag = jpegs = None
        if mcap is not None:
            bag = stack.enter_context(BagStream(mcap, table_columns(springs) + tuple(extra)))
            jpegs = stack.enter_context(contextlib.closing(recorded_jpegs(video)))
        for row, (frame, r) in zip(source.rows, rows, strict=True):
            cells = contact.cells(contact.update(frame, r, rest_log)) if contact else []
            writer.write(frame.t_s, r, cells)
            if bag is None:
                continue
            bag.write_row(signal_row(frame.t_s, r, springs) + cells)
            if row["video_frame"] is not None:
                jpeg = next(jpegs)  # the recorder muxed video_frame k as the k-th packet
                if frame.image is not None:  # a frame lost to corruption has no picture
                    bag.write_image(frame.t_s, jpeg)
    return out_csv


def _pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else math.nan


def latency_summary(values_ms: list[float]) -> dict:
    """n, p50, p99, max, mean (ms) of a list of latencies."""
    return {"n": len(values_ms), "p50_ms": _pct(values_ms, 50), "p99_ms": _pct(values_ms, 99),
            "max_ms": max(values_ms) if values_ms else math.nan,
            "mean_ms": float(np.mean(values_ms)) if values_ms else math.nan}  # fmt: skip


@dataclass
class LiveConfig:
    """How a live session runs.

    mode : "latest" (control; stale frames dropped) or "every" (recording).
    record : an ``.avi`` to record the processed frames to (with timestamps).
    udp_port : send one JSON datagram per frame there (``udp_host``, default
        this machine only).
    jsonl : print one JSON line per frame on stdout.
    controls : read r/d/q keys from stdin (None: when stdin is a terminal).
    max_frames, duration_s : stop after so many rows / seconds (None: no limit).
    springs : the suspension's stiffness (Stiffness): adds the forces to every row.
    view_port : serve the browser view there (0: any free port), on ``view_host``.
    calib : a contact calibration (camwhisker.contact.pipeline.Calibration): adds the
        belief, MF and, with ``base_port``, GM, Z, fusion and the contact point.
    eta_deg : the belief's eta as given (default: from the first rest reference).
    base_port : receive base positions there (``base_host``, default this machine only;
        0: a free port), stamped on this machine's monotonic clock, or on any clock
        with ``base_offset_s`` given (t_camera = t_base + offset).
    base_poses : the base datagrams are poses in space (docs/sensor.md section 9): the rows
        add the contact point in W; ``mount`` the sensor's pose in the frame of the
        carrier they are of (camwhisker.io.poses.Mount).
    mcap : an MCAP file to write the rows to as ROS 2 messages, with each frame's JPEG
        bytes (the recording's; else a raw MJPG camera's; else encoded at quality 90), by
        a thread of its own that drops the rows it cannot keep up with (counted).
    lsl : the name of the Lab Streaming Layer outlet of the rows (and of its marker
        outlet, with "-events", for the events); opened with the session, so an inlet
        can connect before the first row.
    base_lsl : take the base positions or poses from the LSL stream of this name (one
        channel or seven; ``base_poses`` is set from it), instead of ``base_port``.
    on_row : called with each row as a dict after the row is written to every output
        (table, JSON, UDP, view, LSL; queued for the MCAP's thread), in the session's
        thread; its return value is ignored.
        The dict holds the JSON line's fields (frame, seq, t_s, dz_mm, phi_deg, theta_deg,
        ok, latency_ms, note, the forces and contact fields where set) as plain floats, ints
        and None, rounded as the table's cells. ``latency_ms`` (capture to result) ends
        before the outputs and the callback, so it excludes the callback's time; that time
        is measured per row (the report's and sidecar's ``on_row_ms``) and delays the next
        frame, which in "latest" mode drops frames when the callback is slower than the
        camera. A callback that raises stops the session: outputs closed as on Ctrl-C,
        then :class:`RowCallbackError` naming the callback and frame.
    """

    mode: str = "latest"
    options: FrontEndOptions = field(default_factory=FrontEndOptions)
    record: Path | None = None
    record_rate_fps: float = 30.0
    jpeg_quality: int = JPEG_QUALITY
    udp_port: int | None = None
    udp_host: str = DEFAULT_UDP_HOST
    jsonl: bool = False
    controls: bool | None = None
    max_frames: int | None = None
    duration_s: float | None = None
    max_reconnects: int = MAX_RECONNECTS
    backoff_s: float = BACKOFF_S
    handle_signals: bool = True
    springs: object = None  # camwhisker.sensor.springs.Stiffness
    view_port: int | None = None
    view_host: str = DEFAULT_VIEW_HOST
    calib: object = None  # camwhisker.contact.pipeline.Calibration
    calib_path: str | None = None
    eta_deg: float | None = None
    base_port: int | None = None
    base_host: str = "127.0.0.1"
    base_offset_s: float | None = None
    base_poses: bool = False
    mount: object = None  # camwhisker.io.poses.Mount
    mcap: Path | None = None
    lsl: str | None = None
    base_lsl: str | None = None
    on_row: Callable[[dict], object] | None = None


@dataclass
class LiveReport:
    """What a live session did (also in its sidecar)."""

    out_csv: Path
    sidecar: Path
    rows: int = 0
    rows_ok: int = 0
    gaps: int = 0
    seq_gaps: int = 0
    grabber: dict = field(default_factory=dict)
    processing: dict = field(default_factory=dict)
    end_to_end: dict = field(default_factory=dict)
    events: list = field(default_factory=list)
    #: The ``on_row`` callback's time per row (latency_summary; empty without one).
    on_row_ms: dict = field(default_factory=dict)
    stopped_by: str = ""
    problems: list[str] = field(default_factory=list)
    #: Something failed (exit status 1): the capture lost, no row ok, or frames of a
    #: file lost; a frame rate off the camera's stated one is a problem, not a failure.
    failed: bool = False


class LiveSession:
    """One live run: grabber thread, processing, outputs, controls, sidecar.

    Parameters
    ----------
    capture : a capture (see :mod:`camwhisker.live.capture`)
        Released when the session ends.
    sensor : Sensor
    out_csv : path
        The signal table; ``OUT.json`` beside it is the sidecar.
    config : LiveConfig
    stdout : text stream for the JSON lines.
    """

    def __init__(self, capture, sensor: Sensor, out_csv: str | Path,
                 config: LiveConfig | None = None, stdout=None):  # fmt: skip
        self.capture = capture
        self.sensor = sensor
        self.config = config or LiveConfig()
        self.out_csv = Path(out_csv)
        self.stdout = stdout or sys.stdout
        self.report = LiveReport(self.out_csv, sidecar_path(self.out_csv))
        self._commands: queue.SimpleQueue[str] = queue.SimpleQueue()
        #: Start/stop recording requests, taken at the next row; whether it records.
        self._record_toggles: queue.SimpleQueue[str] = queue.SimpleQueue()
        self.recording = self.config.record is not None
        self._stop = threading.Event()
        self._stop_reason = ""
        self._stdout_closed = False
        #: Sequence numbers of the rows, in order (for the drop check).
        self.seqs: list[int] = []
        #: The rest references built (camwhisker.vision.stream.RestRecord), for the sidecar.
        self.rest_log: list = []
        self._input: dict = {}
        #: The grabbed item of the frame being processed, and when it went in (perf_counter s).
        self._grabbed: Grabbed | None = None
        self._handed_at = 0.0
        #: Why the first row was untrusted (said where no row is ok).
        self._first_reason = ""
        #: The contact's fields per row, and the base positions' receiver (camera clock
        #: from the first frame's monotonic time, ``_t0``).
        self.contact: RowContact | None = None
        self.base: BaseReceiver | LslBaseReceiver | None = None
        self._t0 = math.nan
        self.base_samples: list[tuple] = []
        #: The on_row callback's time per row (ms), and its failure (said in the problems).
        self.on_row_ms: list[float] = []
        self._on_row_error = ""
        try:
            self._open_base()
        except (OSError, ValueError):
            if self.base is not None:
                self.base.stop()
            capture.release()
            raise
        cfg = self.config
        if cfg.calib is not None:
            self.contact = RowContact(cfg.calib, 1.0 / cfg.record_rate_fps, cfg.eta_deg,
                                      base=self.base is not None, poses=cfg.base_poses,
                                      mount=cfg.mount)  # fmt: skip
        source = getattr(capture, "source", None)  # a file or folder: its size is known now
        if source is not None:
            try:
                check_frame_size(source, sensor)
            except SourceError:
                capture.release()
                raise
        #: The MCAP stream while the session runs (None without ``config.mcap``).
        self._bag: BagThread | None = None
        #: The browser view (None without one); bound now, so a taken port writes nothing.
        self.view: LiveView | None = None
        if self.config.view_port is not None:
            try:
                self.view = LiveView(PlateModel(sensor), self.command, self.config.view_host,
                                     self.config.view_port)  # fmt: skip
            except OSError:
                capture.release()
                raise
        #: The LSL outlets (None without ``config.lsl``): open now, for inlets to connect to.
        self._lsl: LslOutlet | None = None
        if cfg.lsl is not None:
            try:
                self._lsl = LslOutlet(cfg.lsl, table_columns(cfg.springs) + tuple(
                    self.contact.fields if self.contact else ()))
            except LslError:
                if self.view is not None:
                    self.view.close()
                if self.base is not None:
                    self.base.stop()
                capture.release()
                raise

    def _open_base(self) -> None:
        """The base's receiver (UDP or LSL), with the checks of its options; an LSL stream
        says whether it gives poses."""
        cfg = self.config
        if cfg.base_port is None and cfg.base_lsl is None:
            return
        if cfg.base_port is not None and cfg.base_lsl is not None:
            raise ValueError("the base from UDP (--base-udp) or from LSL (--base-lsl), not both")
        if cfg.calib is None:
            raise ValueError("base positions need a contact calibration (calib)")
        if cfg.base_port is not None:
            self.base = BaseReceiver(cfg.base_port, cfg.base_host, poses=cfg.base_poses)
            return
        if cfg.base_offset_s is not None:
            raise LslError("--base-offset-s goes with --base-udp: LSL corrects the clocks")
        self.base = LslBaseReceiver(cfg.base_lsl)
        if cfg.mount is not None and not self.base.poses:
            raise LslError(f"--mount goes with base poses: {self.base.where} gives positions "
                           "(1 channel)")  # fmt: skip
        self.config = dataclasses.replace(cfg, base_poses=self.base.poses)

    # -------------------------------------------------------------- control
    def command(self, name: str) -> None:
        """Queue "rezero", "redetect", "record" (start/stop) or "quit" (thread-safe)."""
        if name == "quit":
            self.stop("quit")
        elif name in ("rezero", "redetect"):
            self._commands.put(name)
        elif name == "record":
            if self.config.record is None:
                raise ValueError("no recording: start live with --record SESSION.avi")
            self._record_toggles.put(name)
        else:
            raise ValueError(f"unknown command {name!r}")

    def stop(self, reason: str = "stop") -> None:
        if not self._stop.is_set():
            self._stop_reason = reason
        self._stop.set()

    def _on_signal(self, signum, _frame) -> None:
        self.stop(signal.Signals(signum).name)

    def _next_event(self) -> str:
        try:
            return self._commands.get_nowait()
        except queue.Empty:
            return ""

    def _keys(self) -> None:
        """Read single keys from a terminal until the session stops."""
        import termios
        import tty

        fd = sys.stdin.fileno()
        saved = termios.tcgetattr(fd)
        try:
            tty.setcbreak(fd)
            while not self._stop.is_set():
                ready, _, _ = select.select([fd], [], [], POLL_S)
                if not ready:
                    continue
                key = os.read(fd, 1).decode(errors="ignore").lower()
                if key in KEYS:
                    log.info("key %r: %s", key, KEYS[key])
                    try:
                        self.command(KEYS[key])
                    except ValueError as exc:  # "s" without --record
                        log.warning("%s", exc)
        finally:
            termios.tcsetattr(fd, termios.TCSADRAIN, saved)

    # ------------------------------------------------------------------ run
    def run(self) -> LiveReport:
        cfg = self.config
        # The MCAP's images need JPEG bytes: the recording's, else kept, else made later.
        prepare = (MjpgRoundTrip(cfg.jpeg_quality) if cfg.record
                   else decode_keeping_jpeg if cfg.mcap else decode_only)  # fmt: skip
        grabber = Grabber(self.capture, cfg.mode, prepare, cfg.max_reconnects, cfg.backoff_s)
        self.out_csv.parent.mkdir(parents=True, exist_ok=True)
        if cfg.mcap is not None:  # first: a bag that cannot be opened leaves nothing open
            self._bag = BagThread(cfg.mcap, table_columns(cfg.springs) + tuple(
                self.contact.fields if self.contact else ()))
        try:
            writer = SignalWriter(self.out_csv, flush=True, springs=self.config.springs,
                                  extra=self.contact.fields if self.contact else ())
            recorder = SessionRecorder(cfg.record, cfg.record_rate_fps) if cfg.record else None
            udp = UdpSender(cfg.udp_port, cfg.udp_host) if cfg.udp_port is not None else None
        except BaseException:
            if self._bag is not None:  # the old bag stays; no temporary file left
                self._bag.discard()
            raise
        controls = cfg.controls if cfg.controls is not None else sys.stdin.isatty()
        keys = threading.Thread(target=self._keys, name="camwhisker-keys", daemon=True)
        old_handlers = {}
        if cfg.handle_signals and threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                old_handlers[sig] = signal.signal(sig, self._on_signal)
        proc_ms: list[float] = []
        e2e_ms: list[float] = []
        self.contact_ms: list[float] = []
        t_start = time.monotonic()
        self._input = describe(self.capture)  # a released cv2.VideoCapture cannot say
        # Everything alive now (modules, compiled code, the front end) lives as long
        # as the session: out of the garbage collector's full passes, which would
        # otherwise walk its ~130,000 objects for ~50 ms in the middle of a frame.
        gc.freeze()
        if self.view is not None:
            self.view.start()
            # The only place the token is shown (off loopback): not in the sidecar.
            log.info("view at %s", self.view.page_url)
        if self.base is not None:
            self.base.start()
        grabber.start()
        if controls:
            keys.start()
            record = ", s = start/stop recording" if cfg.record else ""
            print(f"camwhisker live: keys r = re-zero, d = re-detect{record}, q = quit",
                  file=sys.stderr)  # fmt: skip
        try:
            frames = self._frames(grabber, t_start)
            rows = stream(frames, self.sensor, cfg.options, strict=False, warm_up=True,
                          rest_log=self.rest_log)  # fmt: skip
            for frame, r in rows:
                proc_s = time.perf_counter() - self._handed_at
                self._row(frame, r, proc_s, writer, recorder, udp, proc_ms, e2e_ms)
        finally:
            gc.unfreeze()
            if self.view is not None:
                self.view.close()
            grabber.stop()
            if self.base is not None:
                self.base.stop()
                self._take_base()
            if keys.is_alive():
                self._stop.set()
                keys.join()
            self.capture.release()
            for sig, handler in old_handlers.items():
                signal.signal(sig, handler)
            writer.close()
            sync_file(self.out_csv)  # streamed under its name: on the disk before the sidecar
            if recorder is not None:
                recorder.close()
            if udp is not None:
                udp.close()
            if self._lsl is not None:
                self._lsl.close()
            try:
                if self._bag is not None:  # stopped too: the summary makes it a bag
                    self._bag.close()
            finally:
                self._finish(grabber, proc_ms, e2e_ms, recorder, udp)
        return self.report

    def _frames(self, grabber: Grabber, t_start: float) -> Iterator[Frame]:
        """The grabbed frames, timed from the first, with their events, until the session
        stops; each one's grabbed item and hand-over time are kept for its row."""
        cfg = self.config
        t0 = None
        while not self._stop.is_set():
            if cfg.max_frames is not None and self.report.rows >= cfg.max_frames:
                self.stop("max_frames")
                return
            if cfg.duration_s is not None and time.monotonic() - t_start >= cfg.duration_s:
                self.stop("duration")
                return
            item = grabber.get(POLL_S)
            if item is None:
                if grabber.finished:
                    self.stop("capture lost" if grabber.stats.lost else "end of input")
                continue
            t0 = item.t_s if t0 is None else t0
            self._t0 = t0
            event = "gap" if item.image is None else self._next_event()
            self._grabbed = item
            frame = Frame(self.report.rows, item.t_s - t0, item.image, event)
            self._handed_at = time.perf_counter()
            yield frame

    def _row(self, frame: Frame, r: FrameResult, proc_s: float, writer, recorder, udp,
             proc_ms, e2e_ms) -> None:  # fmt: skip
        rep = self.report
        item = self._grabbed
        done = time.monotonic()
        n_events = len(rep.events)  # those this row adds go to LSL's markers
        if item.image is not None:
            proc_ms.append(1e3 * proc_s)
            e2e_ms.append(1e3 * (done - item.t_s))
        else:
            rep.gaps += 1
        if frame.event in ("rezero", "redetect"):
            rep.events.append({"frame": frame.index, "event": frame.event, "ok": bool(r.ok)})
        if self.seqs:
            rep.seq_gaps += item.seq - self.seqs[-1] - 1
        self.seqs.append(item.seq)
        extra, cells = None, ()
        if self.contact is not None:
            tic = time.perf_counter()
            if self.base is not None:
                self._take_base()
            values = self.contact.update(frame, r, self.rest_log)
            cells = self.contact.cells(values)
            extra = self.contact.message(values, cells)
            self.contact_ms.append(1e3 * (time.perf_counter() - tic))
        writer.write(frame.t_s, r, cells)
        if recorder is not None and not self._record_toggles.empty():
            self._record_toggles.get_nowait()
            self.recording = not self.recording
            what = "record-start" if self.recording else "record-stop"
            rep.events.append({"frame": frame.index, "event": what, "ok": True})
        if self.view is not None:
            self.view.publish(frame, r, 1e3 * (done - item.t_s), rep.seq_gaps,
                              self.recording if recorder is not None else None, extra)  # fmt: skip
        if recorder is not None and self.recording:
            shape = None if item.image is None else item.image.shape
            recorder.write(frame.index, item.seq, frame.t_s, item.jpeg, shape, frame.event)
        if self.config.jsonl or udp is not None:
            msg = result_message(item.seq, frame.t_s, r, 1e3 * (done - item.t_s),
                                 self.config.springs, extra)  # fmt: skip
            if self.config.jsonl and not self._stdout_closed:
                try:
                    print(msg, file=self.stdout, flush=True)
                except BrokenPipeError:  # the reader went away: the other outputs go on
                    self._stdout_closed = True
                    log.warning("stdout closed: no more JSON lines")
            if udp is not None:
                udp.send(msg)
        if self._lsl is not None or self._bag is not None:
            cells = signal_row(frame.t_s, r, self.config.springs) + list(cells)
        if self._lsl is not None:
            self._lsl.push_row(cells, item.t_s)
            for event in rep.events[n_events:]:
                self._lsl.push_event(event["event"], item.t_s)
        if self._bag is not None:  # queued for the bag's thread: the loop never waits on it
            jpeg = item.jpeg
            if jpeg is None and item.image is not None:  # encoded in the bag's thread
                jpeg = functools.partial(encode_jpeg, item.image)
            self._bag.put(cells, frame.t_s, jpeg)
        if rep.rows == 0 and not r.ok:
            self._first_reason = r.reason
        rep.rows += 1
        rep.rows_ok += bool(r.ok)
        if self.config.on_row is not None:  # last: the row is in every output before it
            self._call_on_row(item.seq, frame.t_s, r, 1e3 * (done - item.t_s), extra)

    def _call_on_row(self, seq: int, t_s: float, r: FrameResult, latency_ms: float,
                     extra: dict | None) -> None:  # fmt: skip
        """Hand the row to ``config.on_row``, timed; a raise stops the session."""
        row = result_fields(seq, t_s, r, latency_ms, self.config.springs, extra)
        callback = self.config.on_row
        tic = time.perf_counter()
        try:
            callback(row)
        except Exception as exc:
            name = getattr(callback, "__qualname__", None) or repr(callback)
            self._on_row_error = (f"on_row callback {name} raised at frame {row['frame']}: "
                                  f"{type(exc).__name__}: {exc}")  # fmt: skip
            self.stop("on_row error")
            raise RowCallbackError(self._on_row_error) from exc
        finally:
            self.on_row_ms.append(1e3 * (time.perf_counter() - tic))

    def _take_base(self) -> None:
        """Move the positions received so far to the contact, on the camera clock
        (from the first frame's time: none before it)."""
        if not math.isfinite(self._t0):
            return
        cfg = self.config
        # A sender on this machine's monotonic clock, else the given offset.
        offset = -self._t0 if cfg.base_offset_s is None else cfg.base_offset_s
        for t, x, arrived in self.base.take():
            # Rounded as the base log holds them, so a replay reads the same numbers.
            sample = (round(t + offset, 9), x, round(arrived - self._t0, 9))
            self.base_samples.append(sample)
            self.contact.put(*sample)

    def _contact_record(self) -> dict | None:
        """The sidecar's ``contact`` entry (and the base log written); what is missing is
        named in the problems (not a failure: the pose rows are all there)."""
        cfg = self.config
        if self.contact is None:
            return None
        out = {"calib": cfg.calib_path, **self.contact.describe(),
               "latency": latency_summary(self.contact_ms)}
        if out["eta_deg"] is None:
            why = out["eta_from"] or "none: no rest reference was built"
            self.report.problems.append(f"no contact belief: eta {why}")
        what = "pose" if cfg.base_poses else "position"
        if self.base is not None and not self.base.received:
            dropped = "; ".join(f"{n} dropped: {k}" for k, n in self.base.rejected.items())
            self.report.problems.append(f"no base {what} received from {self.base.where}: no GM, "
                                        f"Z, fusion or contact point"
                                        + (f" ({dropped})" if dropped else ""))  # fmt: skip
        if self.base is not None:
            if cfg.base_poses:
                path = write_pose_log(pose_log_path(self.out_csv), self.base_samples)
            else:
                path = write_base_log(base_log_path(self.out_csv), self.base_samples)
            m = cfg.mount
            lsl = cfg.base_lsl is not None
            out["base"] = {
                **(self.base.describe() if lsl else {"address": list(self.base.address)}),
                "received": self.base.received,
                "rejected": self.base.rejected, "log": str(path), "kind": what + "s",
                "mount": None if m is None else [*map(float, m.position_mm), *map(float, m.quat)],
                "clock": ("the sender's LSL clock, corrected (time_correction_s) to this "
                          "machine's, then to its monotonic clock (clock_offset_s)" if lsl
                          else "this machine's monotonic clock" if cfg.base_offset_s is None
                          else f"t_camera = t_base + {cfg.base_offset_s!r} s"),
            }
        return out

    def _finish(self, grabber: Grabber, proc_ms, e2e_ms, recorder, udp) -> None:
        rep = self.report
        cfg = self.config
        stats = grabber.stats
        rep.stopped_by = self._stop_reason or "end of input"
        rep.grabber = dataclasses.asdict(stats)
        rep.grabber["fps_measured"] = stats.fps_measured
        # grabbed = rows + dropped + left_at_stop (a stop by quit / signal / max_frames)
        rep.grabber["left_at_stop"] = grabber.pending
        rep.processing = latency_summary(proc_ms)
        rep.end_to_end = latency_summary(e2e_ms)
        if rep.rows and not rep.rows_ok:
            rep.problems.append(f"no row of {rep.rows} is ok (the first: {self._first_reason})")
        source = getattr(self.capture, "source", None)  # a file's frames lost, or its end
        lost_frames = source.problem if source is not None else ""
        if lost_frames:
            rep.problems.append(lost_frames)
        rep.failed = bool(stats.lost or not rep.rows_ok or lost_frames or self._on_row_error)
        if self._on_row_error:
            rep.problems.append(self._on_row_error)
        latency = {"processing": rep.processing, "end_to_end": rep.end_to_end}
        if cfg.on_row is not None:
            rep.on_row_ms = latency["on_row_ms"] = latency_summary(self.on_row_ms)
        if stats.lost:
            rep.problems.append(f"capture lost after {cfg.max_reconnects} reconnect attempts")
        applied_fps = self._input.get("settings", {}).get("applied", {}).get("fps")
        measured = stats.fps_measured
        if (
            applied_fps
            and math.isfinite(measured)
            and (abs(measured - applied_fps) > FPS_MISMATCH * applied_fps)
        ):
            rep.problems.append(f"the camera reports {applied_fps:g} fps; measured {measured:.1f}")
        if stats.failed_reads:
            rep.problems.append(f"{stats.failed_reads} failed read(s), {stats.reconnects} "
                                f"reconnect(s); {rep.gaps} row(s) without a frame")  # fmt: skip
        if self._bag is not None and self._bag.dropped:
            rep.problems.append(f"{self._bag.dropped} row(s) not in the MCAP bag (with their "
                                "images): the disk was slower than the frames")  # fmt: skip
        contact = self._contact_record()
        source = describe(self.capture) if hasattr(self.capture, "describe") else self._input
        meta = sidecar(
            "camwhisker.live.loop.LiveSession", source,
            "capture (monotonic clock, from the first frame)",
            (rep.rows, rep.rows_ok), rep.problems, cfg.options, self.sensor,
            rest=self.rest_log,
            springs=cfg.springs,
            mode=cfg.mode,
            rows_without_frame=rep.gaps,
            stopped_by=rep.stopped_by,
            grabber=rep.grabber,
            dropped=stats.dropped,
            latency=latency,
            events=rep.events,
            recording=None if recorder is None else {
                "video": str(recorder.video), "timestamps": str(recorder.timestamps),
                "frames": recorder.frames, "jpeg_quality": cfg.jpeg_quality},
            udp=None if udp is None else {"address": list(udp.address), "sent": udp.sent,
                                          "errors": udp.errors},
            view=None if self.view is None else {"url": self.view.url,
                                                 "pictures": self.view.pictures,
                                                 "requests": self.view.requests,
                                                 "rejected_requests": self.view.rejected},
            contact=contact,
            mcap=None if self._bag is None else {"file": str(self._bag.path),
                                                 "rows": self._bag.rows,
                                                 "images": self._bag.images,
                                                 "dropped": self._bag.dropped},
            lsl=None if self._lsl is None else self._lsl.describe(self._t0),
        )  # fmt: skip
        write_sidecar(self.out_csv, meta)

    @staticmethod
    def summary(rep: LiveReport) -> str:
        """The end-of-run lines (printed by the command)."""
        g, p, e = rep.grabber, rep.processing, rep.end_to_end
        return "\n".join([
            f"{rep.rows} rows, {rep.rows_ok} ok, {rep.gaps} without a frame -> {rep.out_csv}, "
            f"{rep.sidecar} (stopped by {rep.stopped_by})",
            f"grabbed {g.get('grabbed', 0)} ({g.get('mode')}), dropped {g.get('dropped', 0)}, "
            f"measured {g.get('fps_measured', math.nan):.1f} fps, "
            f"reconnects {g.get('reconnects', 0)}",
            f"processing latency p50 {p['p50_ms']:.2f} ms, p99 {p['p99_ms']:.2f} ms; "
            f"end to end p50 {e['p50_ms']:.2f} ms, p99 {e['p99_ms']:.2f} ms",
        ])  # fmt: skip


def run_live(capture, sensor: Sensor, out_csv: str | Path, config: LiveConfig | None = None,
             stdout=None) -> LiveReport:  # fmt: skip
    """Run a :class:`LiveSession` to its end; returns its report."""
    return LiveSession(capture, sensor, out_csv, config, stdout).run()
