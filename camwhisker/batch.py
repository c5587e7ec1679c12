"""Batch processing: a video in, the signal table (SENSOR.md section 6) out.

:func:`run_batch` drives :func:`camwhisker.vision.tracker.track` over a
:mod:`camwhisker.sources` source and writes ``OUT.csv`` and its sidecar
``OUT.json`` (version, input, sensor, options, counts, problems). Both are
written to temporary files and renamed into place, so a crash never leaves a
table that looks whole. Untrusted values are empty cells; so is theta where
phi is too small to define it.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from camwhisker import __version__
from camwhisker.atomic import atomic_path
from camwhisker.sensor import Sensor, sensor_to_dict
from camwhisker.sources import open_source
from camwhisker.vision import tracker as _tracker
from camwhisker.vision.tracker import FrameResult, FrontEndOptions, track

__all__ = [
    "SIGNAL_COLUMNS", "BatchReport", "run_batch", "signal_row", "write_signals", "sidecar_path",
]

#: Required columns first (SENSOR.md section 6), then diagnostics.
SIGNAL_COLUMNS = (
    "frame", "t_s", "dz_mm", "phi_deg", "theta_deg", "ok",
    "sx_mm", "sy_mm", "phi_sigma_deg", "n_corners", "rms_px", "note",
)  # fmt: skip
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


def sidecar_path(out_csv: Path) -> Path:
    out_csv = Path(out_csv)
    return out_csv.with_suffix(".json")


def _cell(x: float, fmt: str) -> str:
    return "" if x is None or not math.isfinite(x) else format(x, fmt)


def signal_row(t_s: float, r: FrameResult) -> list:
    """One row of the signal table (:data:`SIGNAL_COLUMNS`), as batch and live write it.

    Untrusted estimates (ok = 0) are empty cells, never numbers.
    """
    ok = bool(r.ok)
    return [
        r.frame, _cell(t_s, ".6f"),
        _cell(r.dz_mm, ".5f") if ok else "",
        _cell(r.phi_deg, ".5f") if ok else "",
        _cell(r.theta_deg, ".3f") if ok else "",
        int(ok),
        _cell(r.sx_mm, ".5f") if ok else "",
        _cell(r.sy_mm, ".5f") if ok else "",
        _cell(r.phi_sigma_deg, ".5f"),
        r.n_corners, _cell(r.rms_px, ".3f"), r.reason,
    ]  # fmt: skip


def write_signals(path: Path, rows: Iterable[tuple[float, FrameResult]]) -> tuple[int, int]:
    """Write (t_s, result) rows as the signal table; returns (rows, rows ok).

    ``path`` is written directly; wrap it in an atomic path for safety.
    """
    n = n_ok = 0
    with open(path, "w", newline="") as fh:
        out = csv.writer(fh)
        out.writerow(SIGNAL_COLUMNS)
        for t_s, r in rows:
            out.writerow(signal_row(t_s, r))
            n += 1
            n_ok += bool(r.ok)
    return n, n_ok


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
    meta = {
        "camwhisker_version": __version__,
        "made_by": "camwhisker.batch.run_batch",
        "input": str(Path(video)),
        "time_source": f"session timestamps ({stamps.name})" if session else source.time_source,
        "fps": source.fps,
        "rest_frame": rest_index,
        "frames": report.frames,
        "frames_ok": report.frames_ok,
        "problems": report.problems,
        "options": dataclasses.asdict(options),
        "constants": {
            "PHI_MIN_FOR_THETA_DEG": _tracker.PHI_MIN_FOR_THETA_DEG,
            "QUALITY_MIN": _tracker.QUALITY_MIN,
            "MIN_CORNERS": _tracker.MIN_CORNERS,
            "MAX_RMS_PX": _tracker.MAX_RMS_PX,
        },
        "sensor_file": sensor.source,
        "sensor": sensor_to_dict(sensor),
        "columns": list(SIGNAL_COLUMNS),
    }
    with atomic_path(report.sidecar) as tmp:
        tmp.write_text(json.dumps(meta, indent=2) + "\n")
    return report
