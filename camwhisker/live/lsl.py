"""Lab Streaming Layer (docs/robots.md): the live rows and events out, base positions or poses in.

``live --lsl NAME`` opens two outlets while the session runs:

- NAME, type :data:`STREAM_TYPE`: one ``double64`` channel per numeric column of the signal
  table, in its order (``frame``, ``t_s``, ``dz_mm``, ... the forces and the contact's
  fields where the table has them; the text columns have none), each cell as the table
  holds it (an empty cell: NaN). The channels' labels and units are in the stream's
  description (``channels/channel/label``, ``unit``). Each sample is stamped with its
  frame's capture time on LSL's clock (``pylsl.local_clock()``): the session's monotonic
  frame time plus the two clocks' offset, measured when the outlet opens.
- NAME + :data:`EVENTS_SUFFIX`, type ``Markers``: one string sample per session event
  (``rezero``, ``redetect``, ``record-start``, ``record-stop``), stamped as the row of the
  frame it took effect at.

``live --base-lsl NAME`` takes the robot's base from the LSL stream NAME: one channel
(``x_mm``, positions) or seven (``x_mm, y_mm, z_mm, qw, qx, qy, qz``, poses, quaternion
scalar first), the channel count saying which; each sample's time is its LSL time stamp,
brought onto this machine's LSL clock with the inlet's ``time_correction()`` and from there
onto the monotonic clock. The samples then go where ``--base-udp``'s datagrams go
(:class:`~camwhisker.live.base.SampleReceiver`).

``pylsl`` (the extra ``lsl``) is imported only when a stream is opened: the package runs
without it.
"""

from __future__ import annotations

import ctypes
import math
import time
from collections.abc import Sequence

from camwhisker import __version__
from camwhisker.live.base import POLL_S, SampleReceiver, check_quaternion

__all__ = ["INSTALL_HINT", "STREAM_TYPE", "EVENTS_SUFFIX", "RESOLVE_S", "LINGER_S",
           "BASE_CHANNELS", "LslError", "lsl_module", "clock_offset_s", "channel_unit",
           "LslOutlet", "LslBaseReceiver"]  # fmt: skip

#: The extra that installs pylsl (pyproject.toml), named where it is missing.
INSTALL_HINT = "pip install 'camwhisker[lsl]'"
#: The signals outlet's content type.
STREAM_TYPE = "whisker"
#: The marker outlet's name is the signals outlet's plus this.
EVENTS_SUFFIX = "-events"
#: How long ``--base-lsl`` looks for its stream, and for the first clock correction (s).
RESOLVE_S = 5.0
#: At the end, connected inlets get this long to take the last samples (s): an outlet
#: that closes drops what its inlets have not pulled yet.
LINGER_S = 0.1
#: The base stream's channels: positions (one) or poses (seven).
BASE_CHANNELS = {1: ("x_mm",), 7: ("x_mm", "y_mm", "z_mm", "qw", "qx", "qy", "qz")}
# Cells of these columns are text, not numbers: they have no channel.
_TEXT_COLUMNS = ("note", "doubt")
# A column's unit from its name's ending (longest first); others have none.
_UNITS = (("_mm_s", "mm/s"), ("_Nmm", "N mm"), ("_mN", "mN"), ("_mm", "mm"), ("_deg", "deg"),
          ("_px", "px"), ("_ms", "ms"), ("_s", "s"))  # fmt: skip
# How many paired readings of the two clocks their offset is taken from.
_CLOCK_READS = 9


class LslError(ValueError):
    """An LSL stream that cannot be opened or used; the message names the stream."""


def lsl_module(error: type[Exception] = LslError):
    """The pylsl package, or ``error`` saying how to install it."""
    try:
        import pylsl
    except ImportError:
        raise error(f"Lab Streaming Layer needs the package pylsl, which is not installed: "
                    f"{INSTALL_HINT}") from None  # fmt: skip
    return pylsl


def clock_offset_s(lsl_clock, clock=time.monotonic) -> float:
    """LSL's clock minus ``clock`` (s): of :data:`_CLOCK_READS` readings of LSL's clock, each
    between two of ``clock``, the one in the narrowest bracket, against its middle."""
    best = (math.inf, 0.0)
    for _ in range(_CLOCK_READS):
        a = clock()
        t = lsl_clock()
        b = clock()
        best = min(best, (b - a, t - (a + b) / 2))
    return best[1]


def channel_unit(column: str) -> str:
    """A column's unit from its name (``dz_mm``: mm, ``fz_mN``: mN); "" for counts, flags
    and unit vectors."""
    for suffix, unit in _UNITS:
        if column.endswith(suffix):
            return unit
    return ""


def _gil_push(pylsl, n: int):
    """``push(outlet, values, t)``: liblsl's push of one double sample, called holding the
    GIL (PyDLL), or None where the library cannot be so loaded (pylsl's push is used).

    The push only queues the sample (microseconds); pylsl's, through ctypes.CDLL, lets the
    GIL go and waits up to the switch interval (5 ms) to get it back from the grabber
    thread: up to 5 ms on a row's way out."""
    try:
        fn = ctypes.PyDLL(pylsl.lib.libpath).lsl_push_sample_dtp
    except (AttributeError, OSError):
        return None
    fn.restype = ctypes.c_int32
    fn.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_double), ctypes.c_double,
                   ctypes.c_int32]  # fmt: skip
    sample = ctypes.c_double * n
    check = pylsl.util.handle_error

    def push(outlet, values, t_s):
        check(fn(outlet.obj, sample(*values), t_s, 1))  # 1: pushthrough, as pylsl's default

    return push


def _number(cell) -> float:
    """A table cell as a number (an empty cell: NaN)."""
    return math.nan if cell == "" else float(cell)


class LslOutlet:
    """The signals and marker outlets of a live session (module docstring).

    Parameters
    ----------
    name : str
        The signals stream's name; the markers' is ``name`` + :data:`EVENTS_SUFFIX`.
    columns : sequence of str
        The signal table's columns, in its order.
    clock : callable
        The clock the frames are stamped with (monotonic seconds).

    Raises
    ------
    LslError
        pylsl not installed, or an empty name.
    """

    def __init__(self, name: str, columns: Sequence[str], clock=time.monotonic):
        pylsl = lsl_module()
        if not name.strip():
            raise LslError("--lsl: the stream's name is empty")
        self.name, self.events_name = name, name + EVENTS_SUFFIX
        columns = list(columns)
        self._index = [i for i, c in enumerate(columns) if c not in _TEXT_COLUMNS]
        self.channels = [columns[i] for i in self._index]
        info = pylsl.StreamInfo(name, STREAM_TYPE, len(self.channels), pylsl.IRREGULAR_RATE,
                                pylsl.cf_double64, f"camwhisker-{name}")  # fmt: skip
        desc = info.desc()
        desc.append_child_value("manufacturer", "camwhisker")
        desc.append_child_value("version", __version__)
        desc.append_child_value("time_stamps", "frame capture time")
        chans = desc.append_child("channels")
        for column in self.channels:
            ch = chans.append_child("channel")
            ch.append_child_value("label", column)
            ch.append_child_value("unit", channel_unit(column))
        markers = pylsl.StreamInfo(self.events_name, "Markers", 1, pylsl.IRREGULAR_RATE,
                                   pylsl.cf_string, f"camwhisker-{self.events_name}")  # fmt: skip
        self._outlet = pylsl.StreamOutlet(info)
        self._markers = pylsl.StreamOutlet(markers)
        #: LSL's clock minus the frames' clock (s): a frame at t is stamped t + offset_s.
        self.offset_s = clock_offset_s(pylsl.local_clock, clock)
        self.rows = self.events = 0
        self._push = _gil_push(pylsl, len(self.channels))

    def push_row(self, cells: Sequence, t_s: float) -> None:
        """One row of the signal table (its cells as the table holds them), its frame
        captured at ``t_s`` on the frames' clock."""
        values = [_number(cells[i]) for i in self._index]
        if self._push is not None:
            self._push(self._outlet, values, t_s + self.offset_s)
        else:
            self._outlet.push_sample(values, t_s + self.offset_s)
        self.rows += 1

    def push_event(self, event: str, t_s: float) -> None:
        """A session event at the frame captured at ``t_s`` (the frames' clock)."""
        self._markers.push_sample([event], t_s + self.offset_s)
        self.events += 1

    def close(self) -> None:
        """Close both outlets, giving connected inlets :data:`LINGER_S` to take the last
        samples first."""
        if self._outlet is None:
            return
        if self._outlet.have_consumers() or self._markers.have_consumers():
            time.sleep(LINGER_S)
        self._outlet = self._markers = None  # pylsl closes an outlet when it is collected

    def describe(self, t0_s: float) -> dict:
        """For the sidecar; ``t0_s`` the first frame's time on the frames' clock (t_s = 0)."""
        return {"name": self.name, "events_name": self.events_name, "type": STREAM_TYPE,
                "channels": [[c, channel_unit(c)] for c in self.channels],
                "rows": self.rows, "events": self.events,
                "clock": "LSL's local_clock = the frames' monotonic clock + clock_offset_s",
                "clock_offset_s": self.offset_s,
                "t0_lsl_s": t0_s + self.offset_s if math.isfinite(t0_s) else None}  # fmt: skip


class LslBaseReceiver(SampleReceiver):
    """Base positions or poses from the LSL stream ``name`` (module docstring), on a daemon
    thread; ``poses`` says which the stream gives.

    Parameters
    ----------
    name : str
        The stream's name, looked for for ``resolve_s`` seconds.
    clock : callable
        The frames' clock (monotonic seconds): samples' times and arrivals are put on it.
    resolve_s : float

    Raises
    ------
    LslError
        pylsl not installed; no stream of that name; a stream with neither 1 nor 7 numeric
        channels; no clock correction within ``resolve_s``.
    """

    def __init__(self, name: str, clock=time.monotonic, resolve_s: float = RESOLVE_S):
        pylsl = lsl_module()
        self.name = name
        found = pylsl.resolve_byprop("name", name, 1, resolve_s)
        if not found:
            raise LslError(f"--base-lsl {name}: no LSL stream of that name found within "
                           f"{resolve_s:g} s")  # fmt: skip
        info = found[0]
        n = info.channel_count()
        if n not in BASE_CHANNELS or info.channel_format() in (pylsl.cf_string,
                                                               pylsl.cf_undefined):
            raise LslError(f"--base-lsl {name}: {n} channel(s) of format "
                           f"{info.channel_format()}; a base stream has numbers, 1 channel "
                           f"(x_mm) or 7 ({', '.join(BASE_CHANNELS[7])})")  # fmt: skip
        self.where = f"LSL stream {name} on {info.hostname()}"
        self.source_id = info.source_id()
        self._channels = BASE_CHANNELS[n]
        self._inlet = pylsl.StreamInlet(info, recover=True)
        try:
            self._inlet.open_stream(resolve_s)
            #: The sender's clock to this machine's LSL clock (s), updated as samples come.
            self.correction_s = self._inlet.time_correction(resolve_s)
        except pylsl.util.TimeoutError:
            self._inlet.close_stream()
            raise LslError(f"--base-lsl {name}: no connection or clock correction within "
                           f"{resolve_s:g} s") from None  # fmt: skip
        #: This machine's LSL clock minus the frames' clock (s).
        self.offset_s = clock_offset_s(pylsl.local_clock, clock)
        self._lost, self._timeout = pylsl.util.LostError, pylsl.util.TimeoutError
        super().__init__(clock, poses=n == 7)

    def _close(self) -> None:
        self._inlet.close_stream()

    def _receive(self):
        try:
            sample, t = self._inlet.pull_sample(timeout=POLL_S)
        except self._lost:  # the sender went and cannot be recovered
            return None
        if sample is None:
            return None
        try:  # updated by LSL in the background: this returns its latest estimate at once
            self.correction_s = self._inlet.time_correction(POLL_S)
        except (self._lost, self._timeout):  # the sender just went: the last estimate
            pass
        return sample, t + self.correction_s - self.offset_s

    def _parse(self, item) -> tuple[float, object]:
        sample, t = item
        for key, v in zip(self._channels, sample, strict=True):
            if not math.isfinite(v):
                raise ValueError(f"channel {key}: not a finite number ({v!r})")
        if not self.poses:
            return t, float(sample[0])
        return t, check_quaternion([float(v) for v in sample], "channels qw-qz")

    def describe(self) -> dict:
        """For the sidecar: the stream and the clock correction last used."""
        return {"lsl_stream": self.name, "source_id": self.source_id, "where": self.where,
                "time_correction_s": self.correction_s, "clock_offset_s": self.offset_s}
