"""ROS 2 messages in MCAP files (docs/robots.md): the signal table out, pose and stage logs in.

Written by :func:`write_signal_bag` (``camwhisker batch --mcap``), in the sensor frame S
(frame_id :data:`FRAME_ID`; docs/sensor.md sections 2 and 9):

- :data:`SIGNALS_TOPIC`, ``camwhisker_msgs/msg/Signals``: one message per table row,
  ``header.stamp`` = the row's t_s to the nanosecond, ``uint32 frame``, ``bool ok`` and one
  float64 per other numeric column, named as the column in lower case (ROS 2 field names
  are: fz_mN is ``fz_mn``, still mN) and in the table's units, NaN where a cell is empty.
- :data:`WRENCH_TOPIC`, ``geometry_msgs/msg/WrenchStamped`` (tables with the forces): SI
  units, the load the whisker puts on the plate, as a force/torque sensor reports it:
  force.z = -fz_mN / 1000 N (fz_mN > 0 pushes the plate toward the camera, along -z_S);
  the torque, mb_Nmm / 1000 N m about the axis z_S x (cos psi, sin psi, 0), psi = theta
  + 180 deg, tilts the whisker toward psi as the load does (section 9). Where theta is
  empty (phi too small to give it) the torque is zero; rows without both forces
  (untrusted) have no message.

Written row by row by :class:`BagStream` (``camwhisker replay --mcap``; ``live --mcap``
through :class:`BagThread`, off the loop's thread):
the same two topics from the live table's rows, and

- :data:`IMAGE_TOPIC`, ``sensor_msgs/msg/CompressedImage``: each frame's JPEG bytes
  (``format`` "jpeg"), stamped as its row;
- :data:`CONTACT_TOPIC`, ``geometry_msgs/msg/PointStamped`` (rows with the contact point
  px_mm, py_mm, pz_mm): the point in the world frame W in metres (frame_id
  :data:`WORLD_FRAME_ID`), for the rows where it is a number.

Read: a source ``FILE.mcap:/topic`` (:func:`bag_source`) gives a pose log
(:func:`read_pose_bag`) from ``geometry_msgs/msg/PoseStamped`` or ``TransformStamped``
(metres to mm, times from header.stamp); :mod:`camwhisker.contact.stage` reads a stage log
through :func:`read_bag_poses`, also from ``PointStamped``.

The packages ``mcap`` and ``mcap-ros2-support`` (the extra ``ros``) are imported only in
the functions that use them: the package runs without them.
"""

from __future__ import annotations

import contextlib
import math
import queue
import re
import threading
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from camwhisker.files.atomic import atomic_path
from camwhisker.files.tables import read_columns, read_header
from camwhisker.io.poses import PoseLog, PoseLogError, pose_log_from_arrays

__all__ = ["INSTALL_HINT", "FRAME_ID", "WORLD_FRAME_ID", "SIGNALS_TOPIC", "WRENCH_TOPIC",
           "IMAGE_TOPIC", "CONTACT_TOPIC", "SIGNALS_TYPE", "WRENCH_TYPE", "IMAGE_TYPE",
           "POINT_TYPE", "POSE_TYPES", "STAGE_TYPES", "QUEUE_ROWS", "BagError", "BagStream",
           "BagThread", "ros_modules",
           "bag_source", "write_signal_bag", "write_table_bag", "read_bag_poses",
           "read_pose_bag"]  # fmt: skip

#: The extra that installs the MCAP packages (pyproject.toml), named where they are missing.
INSTALL_HINT = "pip install 'camwhisker[ros]'"
#: The sensor frame S (docs/sensor.md section 9) as the messages' header.frame_id.
FRAME_ID = "whisker"
SIGNALS_TOPIC = "/whisker/signals"
WRENCH_TOPIC = "/whisker/wrench"
IMAGE_TOPIC = "/whisker/image"
CONTACT_TOPIC = "/whisker/contact"
SIGNALS_TYPE = "camwhisker_msgs/msg/Signals"
WRENCH_TYPE = "geometry_msgs/msg/WrenchStamped"
IMAGE_TYPE = "sensor_msgs/msg/CompressedImage"
POINT_TYPE = "geometry_msgs/msg/PointStamped"
#: The world frame W of the base poses (docs/sensor.md section 9): the contact point's.
WORLD_FRAME_ID = "world"
#: Message types a pose log is read from; a stage log also takes a point.
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/TransformStamped")
STAGE_TYPES = (*POSE_TYPES, "geometry_msgs/msg/PointStamped")
# Cells of these columns are text, not numbers: they have no field.
_TEXT_COLUMNS = ("note", "doubt")
# The contact point's columns (camwhisker.contact.space.WORLD_COLUMNS), in mm.
_POINT_COLUMNS = ("px_mm", "py_mm", "pz_mm")
# ROS 2's rule for a field name (rosidl): the table's names that break it are refused.
_FIELD_NAME = re.compile(r"(?!.*__)(?!.*_$)[a-z][a-z0-9_]*")
_NS = 10**9
#: Rows (with their images) a :class:`BagThread` holds for its writer: 3 s at 30 frames/s,
#: at most ~250 MB of 720p frames yet to encode; more come only while the disk stalls.
QUEUE_ROWS = 90

_SEP = "=" * 80
_HEADER = f"""{_SEP}
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
{_SEP}
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
_WRENCH = f"""std_msgs/Header header
geometry_msgs/Wrench wrench
{_SEP}
MSG: geometry_msgs/Wrench
geometry_msgs/Vector3 force
geometry_msgs/Vector3 torque
{_SEP}
MSG: geometry_msgs/Vector3
float64 x
float64 y
float64 z
{_HEADER}"""
_IMAGE = f"std_msgs/Header header\nstring format\nuint8[] data\n{_HEADER}"
_POINT = f"""std_msgs/Header header
geometry_msgs/Point point
{_SEP}
MSG: geometry_msgs/Point
float64 x
float64 y
float64 z
{_HEADER}"""


class BagError(ValueError):
    """An MCAP bag that cannot be written or read; the message names the file (and topic)."""


def ros_modules(error: type[Exception] = BagError):
    """The mcap and mcap_ros2 packages, or ``error`` saying how to install them."""
    try:
        import mcap.exceptions
        import mcap.reader
        import mcap.writer
        import mcap_ros2.decoder
        import mcap_ros2.writer
    except ImportError:
        raise error(f"MCAP bags need the packages mcap and mcap-ros2-support, which are not "
                    f"installed: {INSTALL_HINT}") from None  # fmt: skip
    return mcap, mcap_ros2


def bag_source(path: str | Path, error: type[Exception] = BagError) -> tuple[Path, str] | None:
    """``(FILE, /topic)`` where ``path`` is ``FILE.mcap:/topic``; None for any other file.

    A bare ``FILE.mcap`` is ``error``: a bag holds many topics, the reader needs one."""
    text = str(path)
    k = text.rfind(":/")
    if k > 0 and text[:k].endswith(".mcap"):
        return Path(text[:k]), text[k + 1:]
    if text.endswith(".mcap"):
        raise error(f"{text}: an MCAP bag: name the topic to read, as {text}:/TOPIC")
    return None


def _stamp(t_s: float) -> dict:
    """builtin_interfaces/Time of ``t_s``: integer nanoseconds, so exact to the nanosecond."""
    sec, nanosec = divmod(round(t_s * 1e9), _NS)
    return {"sec": sec, "nanosec": nanosec}


def _fields(names, path: Path) -> list[tuple[str, str, str]]:
    """(column, field, ROS type) of the Signals message for the columns ``names``: all
    but t_s and the text columns, frame uint32, ok bool, the others float64."""
    fields = []
    for name in names:
        if name == "t_s" or name in _TEXT_COLUMNS:
            continue
        kind = {"frame": "uint32", "ok": "bool"}.get(name, "float64")
        field = name.lower()  # ROS 2 field names are lower case: fz_mN -> fz_mn
        if not _FIELD_NAME.fullmatch(field) or any(f == field for _, f, _ in fields):
            raise BagError(f"{path}: column {name}: {field!r} is not a ROS 2 field name "
                           "(lower case letters, digits, single underscores) or repeats one")
        fields.append((name, field, kind))
    return fields


def _signals_def(fields: list[tuple[str, str, str]]) -> str:
    """The Signals message's definition, its fields in the table's order."""
    return ("std_msgs/Header header\n" + "".join(f"{k} {f}\n" for _, f, k in fields)
            + _HEADER)


def _wrench(fz_mN: float, mb_Nmm: float, theta_deg: float) -> dict:
    """The load on the plate in S (SI): force along -z_S, torque about z_S x (cos psi,
    sin psi, 0) with psi = theta + 180 deg, i.e. about (sin theta, -cos theta, 0)."""
    th = math.radians(theta_deg)
    # Theta empty: phi is too small to give the moment a direction.
    ax, ay = (math.sin(th), -math.cos(th)) if math.isfinite(th) else (0.0, 0.0)
    m = mb_Nmm / 1000.0
    return {"force": {"x": 0.0, "y": 0.0, "z": -fz_mN / 1000.0},
            "torque": {"x": m * ax, "y": m * ay, "z": 0.0}}  # fmt: skip


def write_signal_bag(path: str | Path, columns: dict) -> Path:
    """Write a signal table's columns (name -> array, one value per row) as an MCAP file of
    ROS 2 messages (module docstring), durably; returns ``path``.

    Columns whose values are not numbers (``note``) have no field. t_s must be finite
    and not negative (MCAP's log times are unsigned nanoseconds); log and publish time
    equal the stamp. :data:`WRENCH_TOPIC` is written where the table has ``fz_mN`` and
    ``mb_Nmm``, for the rows where both are numbers (with theta_deg where present).

    Raises
    ------
    BagError
        A missing t_s, a time below 0 or not a number (naming the row as in a file),
        a column name ROS 2 refuses, or the MCAP packages not installed.
    OSError
        Writing failed; it names ``path``, which is left as it was.
    """
    # Text columns (note) have no field: the numbers alone, as a table row's cells.
    names = [c for c, v in columns.items() if np.asarray(v).dtype.kind in "biuf"]
    with BagStream(path, names) as bag:
        for row in zip(*(np.asarray(columns[c]).tolist() for c in names), strict=True):
            bag.write_row(row)
    return Path(path)


def write_table_bag(table: str | Path, path: str | Path) -> Path:
    """Write the signal table at ``table`` (a CSV) as the MCAP file ``path``
    (:func:`write_signal_bag`), every message holding the table's printed values."""
    names = tuple(c for c in read_header(table) if c not in _TEXT_COLUMNS)
    return write_signal_bag(path, read_columns(table, names))


class BagStream:
    """An MCAP file of ROS 2 messages written row by row, while a session runs (live,
    replay): the topics of the module docstring, each message as it comes.

    The file is written under a temporary name beside ``path``; :meth:`close` writes
    MCAP's summary, fsyncs and renames it into place, so ``path`` holds the old file
    (or none) until the end, never part of a bag. Leaving a ``with`` block on an
    exception discards it (:meth:`discard`); a session that is stopped calls
    :meth:`close`. Chunks are not compressed: JPEG does not shrink, and a compressed
    1 MB chunk would cost ~4 ms where it is written, for nothing.

    Parameters
    ----------
    path : path
        The MCAP file.
    columns : sequence of str
        The signal table's columns, in its order (:func:`write_signal_bag`'s fields);
        with fz_mN and mb_Nmm the wrench, with px_mm, py_mm, pz_mm the contact point.

    Raises
    ------
    BagError
        The MCAP packages not installed, no t_s or a column name ROS 2 refuses.
    OSError
        The temporary file cannot be made; it names ``path``.
    """

    def __init__(self, path: str | Path, columns: Sequence[str]):
        self.path = Path(path)
        mcap, mcap_ros2 = ros_modules(BagError)
        columns = list(columns)
        if "t_s" not in columns:
            raise BagError(f"{self.path}: the table has no column t_s for the messages' stamps")
        fields = _fields(columns, self.path)
        # Each message's cell index, field and converter, fixed once: no work per row on it.
        self._fields = [(columns.index(c), f, {"uint32": int, "bool": _is_one}.get(k, _number))
                        for c, f, k in fields]  # fmt: skip
        self._t = columns.index("t_s")
        self._force = ([columns.index(c) for c in ("fz_mN", "mb_Nmm")]
                       if {"fz_mN", "mb_Nmm"} <= set(columns) else None)
        self._theta = columns.index("theta_deg") if "theta_deg" in columns else None
        self._point = ([columns.index(c) for c in _POINT_COLUMNS]
                       if set(_POINT_COLUMNS) <= set(columns) else None)  # fmt: skip
        self.rows = self.images = 0
        self._stack = contextlib.ExitStack()
        try:
            tmp = self._stack.enter_context(atomic_path(self.path))
            fh = self._stack.enter_context(open(tmp, "wb"))  # noqa: SIM115 - closed in close()
            self._writer = mcap_ros2.writer.Writer(
                fh, compression=mcap.writer.CompressionType.NONE)
            w = self._writer
            self._signals = w.register_msgdef(SIGNALS_TYPE, _signals_def(fields))
            self._wrench = w.register_msgdef(WRENCH_TYPE, _WRENCH) if self._force else None
            self._image = w.register_msgdef(IMAGE_TYPE, _IMAGE)
            self._contact = w.register_msgdef(POINT_TYPE, _POINT) if self._point else None
        except BaseException:
            self.discard()
            raise
        self.closed = False

    def write_row(self, cells: Sequence) -> None:
        """One row of the signal table, its cells as the table holds them (empty: NaN):
        its Signals message, and its wrench and contact point where they are numbers.

        Raises
        ------
        BagError
            The row's t_s is not a time from 0 on (naming the row as in a file).
        """
        t = cells[self._t]
        t_s = _number(t)
        if not t_s >= 0:
            raise BagError(f"{self.path}: row {self.rows + 2}, column t_s: {t!r} is not a "
                           "time from 0 on (MCAP's log times are unsigned)")  # fmt: skip
        stamp = _stamp(t_s)
        ns, seq = stamp["sec"] * _NS + stamp["nanosec"], self.rows
        header = {"stamp": stamp, "frame_id": FRAME_ID}
        msg = {f: convert(cells[i]) for i, f, convert in self._fields}
        msg["header"] = header
        write = self._writer.write_message
        write(SIGNALS_TOPIC, self._signals, msg, log_time=ns, publish_time=ns, sequence=seq)
        if self._force is not None:
            fz, mb = (_number(cells[i]) for i in self._force)
            theta = _number(cells[self._theta]) if self._theta is not None else math.nan
            if math.isfinite(fz) and math.isfinite(mb):
                write(WRENCH_TOPIC, self._wrench, {"header": header,
                                                   "wrench": _wrench(fz, mb, theta)},
                      log_time=ns, publish_time=ns, sequence=seq)  # fmt: skip
        if self._point is not None:
            p = [_number(cells[i]) / 1000.0 for i in self._point]  # mm -> m
            if all(math.isfinite(v) for v in p):
                point = {"header": {"stamp": stamp, "frame_id": WORLD_FRAME_ID},
                         "point": dict(zip("xyz", p, strict=True))}  # fmt: skip
                write(CONTACT_TOPIC, self._contact, point, log_time=ns, publish_time=ns,
                      sequence=seq)  # fmt: skip
        self.rows += 1

    def write_image(self, t_s: float, jpeg: bytes) -> None:
        """A frame's JPEG bytes, stamped ``t_s`` to the table's 6 decimals (its row's)."""
        stamp = _stamp(round(t_s, 6))
        ns = stamp["sec"] * _NS + stamp["nanosec"]
        msg = {"header": {"stamp": stamp, "frame_id": FRAME_ID}, "format": "jpeg",
               "data": jpeg}  # fmt: skip
        self._writer.write_message(IMAGE_TOPIC, self._image, msg, log_time=ns,
                                   publish_time=ns, sequence=self.images)  # fmt: skip
        self.images += 1

    def close(self) -> Path:
        """Write the summary, fsync and rename the file into place; returns its path.

        Raises
        ------
        OSError
            Writing failed; it names ``path``, which is left as it was.
        """
        if self.closed:
            return self.path
        self.closed = True
        try:
            self._writer.finish()
        except BaseException:
            self.discard()
            raise
        self._stack.close()
        return self.path

    def discard(self) -> None:
        """Drop the temporary file: ``path`` stays as it was."""
        self.closed = True
        with contextlib.suppress(_Discarded):
            self._stack.__exit__(_Discarded, _Discarded(), None)

    def __enter__(self) -> BagStream:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        elif not self.closed:
            self.discard()


class BagThread:
    """A :class:`BagStream` written by a thread of its own, for a loop that must not wait
    for the disk (``live --mcap``): :meth:`put` queues a row and its image and returns.

    The thread builds the messages and writes them, in the order put; :meth:`close`
    writes what is queued, then closes the stream (its summary, fsync, rename). A row
    put while ``maxsize`` rows wait is dropped with its image and counted
    (:attr:`dropped`): the bag lacks those frames, the session goes on. A write that
    fails stops the writer; the next :meth:`put` and :meth:`close` raise its error, and
    the file is discarded (``path`` stays as it was).

    Parameters
    ----------
    path, columns
        As :class:`BagStream`, which is opened here: its errors are raised at once.
    maxsize : int
        The most rows waiting for the writer (:data:`QUEUE_ROWS`).
    """

    def __init__(self, path: str | Path, columns: Sequence[str], maxsize: int = QUEUE_ROWS):
        self._bag = BagStream(path, columns)
        self.path = self._bag.path
        #: Rows not written because the queue was full (their images with them).
        self.dropped = 0
        self.error: BaseException | None = None
        self._discarding = False
        self._maxsize = maxsize
        # SimpleQueue: a put takes no lock the writer may hold, so the loop never waits on it.
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._write, name="camwhisker-mcap",
                                        daemon=True)  # fmt: skip
        self._thread.start()

    @property
    def rows(self) -> int:
        return self._bag.rows

    @property
    def images(self) -> int:
        return self._bag.images

    def put(self, cells: Sequence, t_s: float, jpeg: bytes | Callable[[], bytes] | None) -> None:
        """Queue a row (:meth:`BagStream.write_row`) and its frame's JPEG captured at
        ``t_s``: the bytes, or a function that makes them, called in the writer's thread
        (None: no image); never waits.

        Raises
        ------
        BagError, OSError
            An earlier row could not be written (the writer's error).
        """
        if self.error is not None:
            raise self.error
        if self._queue.qsize() < self._maxsize:
            self._queue.put((cells, t_s, jpeg))
        else:  # dropped, never waited for: a stalled disk must not stall the control outputs
            self.dropped += 1

    def _write(self) -> None:
        while (item := self._queue.get()) is not None:
            if self.error is not None or self._discarding:
                continue  # the file is discarded: the rows left are not written
            cells, t_s, jpeg = item
            try:
                self._bag.write_row(cells)
                if jpeg is not None:
                    self._bag.write_image(t_s, jpeg() if callable(jpeg) else jpeg)
            except Exception as exc:  # raised in the loop's thread by put and close
                self.error = exc

    def _join(self) -> None:
        if self._thread.is_alive():
            self._queue.put(None)  # after the rows queued: they are written first
            self._thread.join()

    def close(self) -> Path:
        """Write the rows queued, then close the stream; returns its path.

        Raises
        ------
        BagError, OSError
            A row could not be written, or the close failed: ``path`` is left as it was.
        """
        self._join()
        if self.error is not None:
            self._bag.discard()
            raise self.error
        return self._bag.close()

    def discard(self) -> None:
        """Stop the writer and drop the temporary file: ``path`` stays as it was."""
        self._discarding = True
        self._join()
        self._bag.discard()


class _Discarded(Exception):
    """Raised into the temporary file's context to drop it."""


def _number(cell) -> float:
    """A table cell as a number (an empty cell: NaN)."""
    return math.nan if cell == "" else float(cell)


def _is_one(cell) -> bool:
    return cell == 1 or cell == "1"


def _topics(reader) -> dict[str, str]:
    """Each topic of a bag and its message type; a bag without an index is read through."""
    summary = reader.get_summary()
    if summary is not None:
        return {c.topic: summary.schemas[c.schema_id].name if c.schema_id else ""
                for c in summary.channels.values()}  # fmt: skip
    return {c.topic: s.name if s else "" for s, c, _ in reader.iter_messages()}


def _sample(msg) -> tuple[int, tuple, tuple]:
    """Stamp (ns), position (m) and quaternion (w, x, y, z; NaN for a point) of a message."""
    stamp = msg.header.stamp
    if hasattr(msg, "pose"):
        p, q = msg.pose.position, msg.pose.orientation
    elif hasattr(msg, "transform"):
        p, q = msg.transform.translation, msg.transform.rotation
    else:
        p, q = msg.point, None
    quat = (q.w, q.x, q.y, q.z) if q is not None else (math.nan,) * 4
    return stamp.sec * _NS + stamp.nanosec, (p.x, p.y, p.z), quat


def read_bag_poses(path: str | Path, topic: str, accepted: tuple[str, ...] = POSE_TYPES,
                   error: type[Exception] = BagError):  # fmt: skip
    """Times (s, from header.stamp), positions (mm) and quaternions (w, x, y, z) of the
    messages on one topic of an MCAP bag, in log-time order, as arrays (N,), (N, 3),
    (N, 4); a point's quaternion is NaN.

    Raises
    ------
    error
        The file unreadable or not an MCAP bag, the topic missing (the message lists the
        bag's topics), of a type not in ``accepted`` (named, with those accepted) or
        without messages; the MCAP packages not installed. Each names ``FILE:TOPIC``.
    """
    mcap, mcap_ros2 = ros_modules(error)
    source = f"{path}:{topic}"
    stamps, positions, quats = [], [], []
    try:
        with open(path, "rb") as fh:
            reader = mcap.reader.make_reader(
                fh, decoder_factories=[mcap_ros2.decoder.DecoderFactory()])
            topics = _topics(reader)
            if topic not in topics:
                raise error(f"{source}: no topic {topic} in the bag; it has: "
                            f"{', '.join(sorted(topics)) or 'none'}")  # fmt: skip
            if topics[topic] not in accepted:
                raise error(f"{source}: messages of type {topics[topic] or 'unknown'}, "
                            f"expected one of {', '.join(accepted)}")  # fmt: skip
            for _, _, _, msg in reader.iter_decoded_messages(topics=[topic]):
                ns, p, q = _sample(msg)
                stamps.append(ns)
                positions.append(p)
                quats.append(q)
    except OSError as exc:
        raise error(f"{path}: cannot read the bag ({exc.strerror or exc})") from exc
    except mcap.exceptions.McapError as exc:
        raise error(f"{source}: not a readable MCAP bag ({exc})") from exc
    if not stamps:
        raise error(f"{source}: the topic has no messages")
    # Integer nanoseconds over 1e9: Python rounds the quotient once, as a CSV's decimals.
    t = np.array([ns / _NS for ns in stamps], float)
    return t, np.array(positions, float) * 1000.0, np.array(quats, float)


def read_pose_bag(path: str | Path, topic: str) -> PoseLog:
    """A pose log from a topic of PoseStamped or TransformStamped messages (metres to mm),
    checked as a CSV pose log is; its rows are the topic's messages counted from 1.

    Raises
    ------
    PoseLogError
        As :func:`read_bag_poses`, and the pose log's own checks, naming ``FILE:TOPIC``.
    """
    t, p, q = read_bag_poses(path, topic, POSE_TYPES, PoseLogError)
    return pose_log_from_arrays(t, p, q, f"{path}:{topic}", range(1, t.size + 1))
