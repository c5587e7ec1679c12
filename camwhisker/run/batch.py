"""Batch processing: a video in, the signal table (docs/sensor.md section 6) out.

:func:`run_batch` drives the streaming core (:func:`camwhisker.vision.stream.stream`)
over a :mod:`camwhisker.io.sources` source and writes ``OUT.csv``, its sidecar
``OUT.json`` (:mod:`camwhisker.io.signals`) and the rest frame's check image
``OUT.rest.png`` (:func:`camwhisker.run.overlay.write_rest_check`). Each is written
to a temporary file and renamed into place, so a crash never leaves a table
that looks whole.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from tqdm import tqdm

from camwhisker.files.atomic import atomic_path
from camwhisker.io.signals import SignalWriter, sidecar, sidecar_path, write_sidecar
from camwhisker.io.sources import SessionSource, check_frame_size, open_source
from camwhisker.run.overlay import is_rest_row, rest_check_path, write_rest_check
from camwhisker.sensor.file import Sensor
from camwhisker.sensor.model import PlateModel
from camwhisker.vision.stream import Frame, stream
from camwhisker.vision.tracker import FrameResult, FrontEndOptions

if TYPE_CHECKING:
    from camwhisker.sensor.springs import Stiffness

__all__ = ["BatchReport", "run_batch"]

#: Videos longer than this get a progress bar (when progress is on).
PROGRESS_MIN_FRAMES = 100


@dataclass
class BatchReport:
    """What a batch run did: its outputs (``rest_check`` None where no rest frame came),
    counts, and the problems met (empty when none)."""

    out_csv: Path
    sidecar: Path
    rest_check: Path | None = None
    frames: int = 0
    frames_ok: int = 0
    problems: list[str] = field(default_factory=list)


def run_batch(
    video: str | Path,
    sensor: Sensor,
    out_csv: str | Path,
    options: FrontEndOptions | None = None,
    rest_index: int = 0,
    fps: float | None = None,
    progress: bool = True,
    decode_threads: int | None = None,
    springs: Stiffness | None = None,
) -> BatchReport:
    """Process a video (or image folder) into the signal table and its sidecar.

    Parameters
    ----------
    video : path
        A video file OpenCV can read, or a folder of images. A live session
        recording (``SESSION.timestamps.csv`` beside it) is processed with its
        own clock, gaps and events, so its rows equal the live table's.
    sensor : Sensor
    out_csv : path
        Output table; ``OUT.json`` beside it records how it was made, ``OUT.rest.png``
        shows the rest frame's features named, for a check by eye.
    options : FrontEndOptions, optional
    rest_index : int
        The rest (reference) frame; earlier rows are written untrusted.
    fps : float, optional
        Frame rate for an image folder (or a video without one).
    progress : bool
        Show a progress bar on long videos.
    decode_threads : int, optional
        FFmpeg decoding threads (see :class:`camwhisker.io.sources.VideoSource`).
    springs : Stiffness, optional
        Adds the forces' columns fz_mN and mb_Nmm (:data:`camwhisker.io.signals.FORCE_COLUMNS`).

    Returns
    -------
    BatchReport
        ``problems`` lists what went wrong without stopping the run (a
        truncated video); the readable part is always written.

    Raises
    ------
    FileNotFoundError, camwhisker.io.sources.SourceError
        The input is missing or not a video.
    camwhisker.vision.FeaturesNotFound
        The rest frame lacks a feature; nothing is written.
    """
    options = options or FrontEndOptions()
    source = open_source(video, fps, decode_threads)
    check_frame_size(source, sensor)
    session = isinstance(source, SessionSource)
    if session and rest_index != 0:
        raise ValueError(f"{video}: a recorded session keeps its own rest frame "
                         f"(rest_index must be 0, got {rest_index})")  # fmt: skip
    report = BatchReport(Path(out_csv), sidecar_path(out_csv))
    # A recorded session is processed as live processed it: failures are rows.
    rest: list = []
    rows = stream(source, sensor, options, rest_index, strict=not session, rest_log=rest)
    rows = _checking_rest(rows, rest_check_path(report.out_csv), PlateModel(sensor), report)
    try:
        report.frames, report.frames_ok = _write_table(report.out_csv, rows, len(source),
                                                       progress, springs)  # fmt: skip
    except BaseException as exc:
        # Stopped (Ctrl-C, SIGTERM): the check image of a table never written goes too.
        if not isinstance(exc, Exception) and report.rest_check is not None:
            report.rest_check.unlink(missing_ok=True)
        raise
    if source.problem:
        report.problems.append(source.problem)
    if report.frames <= rest_index:
        report.problems.append(f"the video has no frame {rest_index} to use as the rest frame")
    meta = sidecar("camwhisker.run.batch.run_batch", str(Path(video)), source.time_source,
                   (report.frames, report.frames_ok), report.problems, options, sensor,
                   rest_index, rest, springs, fps=source.fps,
                   rest_check=report.rest_check.name if report.rest_check else None)  # fmt: skip
    write_sidecar(report.out_csv, meta)
    return report


def _checking_rest(
    rows: Iterable[tuple[Frame, FrameResult]], path: Path, model: PlateModel, report: BatchReport
) -> Iterator[tuple[Frame, FrameResult]]:
    """The rows, passed on; the first rest frame's check image is written at ``path``
    (recorded in ``report.rest_check``)."""
    for frame, r in rows:
        if report.rest_check is None and is_rest_row(r, frame.event, started=False):
            report.rest_check = write_rest_check(path, frame.image, r, model)
        yield frame, r


def _write_table(
    out_csv: Path, rows: Iterable[tuple[Frame, FrameResult]], total: int, progress: bool,
    springs: Stiffness | None = None,
) -> tuple[int, int]:
    """Write the (frame, result) rows as the table at ``out_csv`` (atomically), with a
    progress bar on long inputs; returns (rows, rows ok)."""
    bar = tqdm(rows, total=total or None, unit="frame", desc="batch",
               disable=not progress or total < PROGRESS_MIN_FRAMES)  # fmt: skip
    with atomic_path(out_csv) as tmp, SignalWriter(tmp, springs=springs) as writer:
        for frame, r in bar:
            writer.write(frame.t_s, r)
    bar.close()
    return writer.rows, writer.rows_ok
