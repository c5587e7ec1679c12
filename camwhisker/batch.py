"""Batch processing: a video in, the signal table (SENSOR.md section 6) out.

:func:`run_batch` drives :func:`camwhisker.vision.tracker.track` over a
:mod:`camwhisker.sources` source and writes ``OUT.csv`` and its sidecar
``OUT.json`` (version, input, sensor, options, counts, problems). Both are
written to temporary files and renamed into place, so a crash never leaves a
table that looks whole. Untrusted values are empty cells; so is theta where
phi is too small to define it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from camwhisker.atomic import atomic_path
from camwhisker.sensor import Sensor
from camwhisker.signals import sidecar, sidecar_path, write_sidecar, write_signals
from camwhisker.sources import open_source
from camwhisker.vision.tracker import FrontEndOptions, track

__all__ = ["BatchReport", "run_batch"]

#: Videos longer than this get a progress bar (when progress is on).
PROGRESS_MIN_FRAMES = 100


@dataclass
class BatchReport:
    """What a batch run did: counts, and the problems met (empty when none)."""

    out_csv: Path
    sidecar: Path
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
        Output table; ``OUT.json`` beside it records how it was made.
    options : FrontEndOptions, optional
    rest_index : int
        The rest (reference) frame; earlier rows are written untrusted.
    fps : float, optional
        Frame rate for an image folder (or a video without one).
    progress : bool
        Show a progress bar on long videos.
    decode_threads : int, optional
        FFmpeg decoding threads (see :class:`camwhisker.sources.VideoSource`).

    Returns
    -------
    BatchReport
        ``problems`` lists what went wrong without stopping the run (a
        truncated video); the readable part is always written.

    Raises
    ------
    FileNotFoundError, camwhisker.sources.SourceError
        The input is missing or not a video.
    camwhisker.vision.FeaturesNotFound
        The rest frame lacks a feature; nothing is written.
    """
    from camwhisker.live.record import timestamps_path

    options = options or FrontEndOptions()
    source = open_source(video, fps, decode_threads)
    out_csv = Path(out_csv)
    report = BatchReport(out_csv, sidecar_path(out_csv))
    times: dict[int, float] = {}
    stamps = timestamps_path(Path(video))
    session = Path(video).is_file() and stamps.is_file()
    if session:
        # A recorded live session: its own clock, gaps and events, as replay reads them.
        from camwhisker.live.loop import session_rows

        if rest_index != 0:
            raise ValueError(f"{video}: a recorded session keeps its own rest frame "
                             f"(rest_index must be 0, got {rest_index})")
        rows = session_rows(video, sensor, options)
    else:

        def frames():
            for f in source:
                times[f.index] = f.t_s
                yield f.image

        rows = ((times.get(r.frame, math.nan), r)
                for r in track(frames(), sensor, options, rest_index))  # fmt: skip
    total = len(source) or None
    bar = tqdm(rows, total=total, unit="frame", desc="batch",
               disable=not progress or (total or 0) < PROGRESS_MIN_FRAMES)  # fmt: skip
    with atomic_path(out_csv) as tmp:
        report.frames, report.frames_ok = write_signals(tmp, bar)
    bar.close()
    if source.problem:
        report.problems.append(source.problem)
    if report.frames <= rest_index:
        report.problems.append(f"the video has no frame {rest_index} to use as the rest frame")
    time_source = f"session timestamps ({stamps.name})" if session else source.time_source
    meta = sidecar("camwhisker.batch.run_batch", str(Path(video)), time_source,
                   (report.frames, report.frames_ok), report.problems, options, sensor,
                   rest_index, fps=source.fps)  # fmt: skip
    write_sidecar(out_csv, meta)
    return report
