"""Many recordings at once: expand inputs, skip what is done, run in parallel, report failures.

One video is one task. A task is any picklable callable ``process(video,
out) -> dict`` that writes ``out`` and its JSON sidecar atomically, the
sidecar last, recording the output's size and SHA-256 (see
:func:`write_sidecar`). An output counts as complete only when its sidecar
says so and the output's bytes still match: a run killed at any point
never leaves a file that is taken as complete, and a rerun skips exactly the
finished files.

Tasks run in this process (``jobs=1``), in ``jobs`` local processes, each with
OpenCV on one thread, or on an existing Dask distributed cluster
(``scheduler``), one video per task. One failed video never stops the others;
the summary lists each failure with its reason. Interrupted (Ctrl-C, SIGTERM),
local runs stop within a few seconds (:mod:`camwhisker.run.workers`): finished outputs
are kept, unfinished ones leave no file, and the summary lists what is left. A run
first removes the temporary files that killed runs left in its output folders.
"""

from __future__ import annotations

import contextlib
import glob
import json
import time
import traceback
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from camwhisker.files.atomic import atomic_path, durable_replace, remove_stale_temps
from camwhisker.files.digest import sha256_file
from camwhisker.io import signals
from camwhisker.io.signals import sidecar_path
from camwhisker.run.workers import run_in_processes, stop_signals_interrupt

__all__ = [
    "VIDEO_SUFFIXES",
    "CampaignError",
    "TaskResult",
    "Summary",
    "expand_inputs",
    "output_path",
    "sidecar_path",
    "write_sidecar",
    "is_complete",
    "run_many",
]

#: What a folder is searched for.
VIDEO_SUFFIXES = frozenset({".avi", ".mp4", ".mov", ".mkv", ".m4v", ".webm", ".mpg", ".mpeg"})


class CampaignError(ValueError):
    """Inputs that cannot be turned into a list of videos (named in the message)."""


@dataclass(frozen=True)
class TaskResult:
    video: str
    out: str
    status: str  # "done", "skipped", "failed" or "left" (not finished when interrupted)
    reason: str = ""
    frames: int = 0
    seconds: float = 0.0


@dataclass
class Summary:
    """The tasks' results, and whether the run was interrupted; ``stale`` lists the
    temporary files of killed earlier runs that this run removed."""

    results: list[TaskResult] = field(default_factory=list)
    seconds: float = 0.0
    interrupted: bool = False
    stale: list[Path] = field(default_factory=list)

    def count(self, status: str) -> int:
        return sum(r.status == status for r in self.results)

    @property
    def failed(self) -> list[TaskResult]:
        return [r for r in self.results if r.status == "failed"]

    @property
    def frames(self) -> int:
        return sum(r.frames for r in self.results if r.status == "done")

    def report(self) -> str:
        lines = []
        if self.stale:
            folders = sorted({str(p.parent) for p in self.stale})
            lines.append(f"removed {len(self.stale)} temporary files that killed runs left "
                         f"in {', '.join(folders)}")  # fmt: skip
        left = f", {self.count('left')} left" if self.interrupted else ""
        lines.append(
            f"{len(self.results)} videos: {self.count('done')} done, "
            f"{self.count('skipped')} already complete, {self.count('failed')} failed{left}; "
            f"{self.frames} frames in {self.seconds:.1f} s"
        )
        lines += [f"  FAILED {r.video}: {r.reason}" for r in self.failed]
        if self.interrupted:
            left_n = self.count("left")
            lines.append(f"interrupted: {left_n} videos left to do, none of them complete "
                         "(partial files removed); the same command again does them")  # fmt: skip
        return "\n".join(lines)


def expand_inputs(items: Sequence[str | Path]) -> list[Path]:
    """Videos named by files, folders (searched recursively by suffix) and globs.

    Order is kept and duplicates dropped. A named file is kept even if it is
    not a video, so that its failure is reported with the others; a folder
    or glob that yields nothing is an error naming it.
    """
    out: list[Path] = []
    for item in items:
        text = str(item)
        path = Path(text)
        if path.is_dir():
            found = sorted(p for p in path.rglob("*") if p.suffix.lower() in VIDEO_SUFFIXES)
            if not found:
                raise CampaignError(f"{path}: folder holds no video ({', '.join(VIDEO_SUFFIXES)})")
        elif glob.has_magic(text):
            found = sorted(Path(p) for p in glob.glob(text, recursive=True) if Path(p).is_file())
            if not found:
                raise CampaignError(f"{text}: pattern matches no file")
        else:
            found = [path]
        out.extend(found)
    seen: set[Path] = set()
    unique = []
    for p in out:
        key = p.resolve()
        if key not in seen:
            seen.add(key)
            unique.append(p)
    return unique


def output_path(
    video: Path, dest: Path | None, suffix: str = ".csv", root: Path | None = None
) -> Path:
    """Where a video's signal table goes.

    Beside the video, or under ``dest`` mirroring the video's folder relative
    to ``root`` (default: the folder that holds ``dest``; folders outside it are
    mirrored from the filesystem root). The rule depends neither on the other
    inputs of a run nor on the working directory, so a rerun from anywhere finds
    its earlier outputs, and equal names in different folders never collide.
    """
    video = Path(video)
    name = video.stem + ".signals" + suffix
    if dest is None:
        return video.with_name(name)
    folder = video.parent.resolve()
    base = Path(root).resolve() if root is not None else Path(dest).resolve().parent
    try:
        rel = folder.relative_to(base)
    except ValueError:
        rel = folder.relative_to(folder.anchor)
    return Path(dest) / rel / name


def write_sidecar(out: Path, meta: dict, complete: bool = True) -> None:
    """Write ``out``'s sidecar (atomically), recording ``out`` as it is now.

    ``complete=False`` records an output that is all there is but not all
    there should be (a truncated video): kept, but redone by the next run.
    """
    out = Path(out)
    output = {"path": out.name, "bytes": out.stat().st_size, "sha256": sha256_file(out)}
    record = dict(meta, output=output, complete=complete)
    signals.write_sidecar(out, record)


def is_complete(out: Path) -> bool:
    """True only if the sidecar says complete and the output's bytes still match it."""
    out, side = Path(out), sidecar_path(Path(out))
    if not (out.is_file() and side.is_file()):
        return False
    try:
        record = json.loads(side.read_text())
        expected = record["output"]
        return (
            record.get("complete") is True
            and expected["bytes"] == out.stat().st_size
            and expected["sha256"] == sha256_file(out)
        )
    except (OSError, ValueError, KeyError, TypeError):
        return False


def _run_one(process: Callable[[Path, Path], dict], video: Path, out: Path) -> TaskResult:
    """Run one task on one core, turning any failure into a result with its reason.

    One core: OpenCV's own threads here (restored afterwards); tasks that
    decode video ask for one decoding thread themselves (:class:`BatchTask`).
    So N workers use N cores, and the throughput of 1 worker is one core's.
    """
    import cv2

    threads = cv2.getNumThreads()
    if threads != 1:  # a forked worker is at 1 already (_opencv_one_thread): setting hangs it
        cv2.setNumThreads(1)
    try:
        return _timed(process, video, out)
    finally:
        if threads != 1:
            cv2.setNumThreads(threads)


def _timed(process, video, out) -> TaskResult:
    t0 = time.perf_counter()
    try:
        info = process(Path(video), Path(out)) or {}
    except Exception as exc:  # noqa: BLE001 - one bad video must not stop the campaign
        last = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
        where = f" (at {Path(last.filename).name}:{last.lineno})" if last else ""
        return TaskResult(
            str(video),
            str(out),
            "failed",
            f"{type(exc).__name__}: {exc}{where}",
            seconds=time.perf_counter() - t0,
        )
    status = "failed" if info.get("error") else "done"
    return TaskResult(
        str(video),
        str(out),
        status,
        info.get("error", ""),
        int(info.get("frames", 0)),
        time.perf_counter() - t0,
    )


def run_many(
    tasks: Iterable[tuple[Path, Path]],
    process: Callable[[Path, Path], dict],
    jobs: int = 1,
    scheduler: str | None = None,
    overwrite: bool = False,
    progress: bool = True,
) -> Summary:
    """Run ``process`` over (video, out) pairs, skipping complete outputs unless ``overwrite``.

    Parameters
    ----------
    jobs : int
        Local worker processes (1: run here).
    scheduler : str, optional
        Address of a Dask distributed scheduler; overrides ``jobs``.

    Returns
    -------
    Summary
        ``interrupted`` where SIGINT or SIGTERM (in the main thread) stopped the run;
        the tasks not finished then are "left", none with a complete output.
    """
    t0 = time.perf_counter()
    tasks = [(Path(video), Path(out)) for video, out in tasks]
    folders = sorted({out.parent for _, out in tasks})
    summary = Summary(stale=[p for f in folders for p in remove_stale_temps(f)])
    todo = []
    for video, out in tasks:
        if not overwrite and is_complete(out):
            summary.results.append(TaskResult(str(video), str(out), "skipped"))
        else:
            todo.append((video, out))
    bar = tqdm(total=len(todo), desc="videos", unit="video", disable=not progress)
    results = _dispatch(todo, process, jobs, scheduler)
    with stop_signals_interrupt():
        try:
            for result in results:
                summary.results.append(result)
                bar.update(1)
                if result.status == "failed" and progress:
                    bar.write(f"FAILED {result.video}: {result.reason}")
        except KeyboardInterrupt:
            summary.interrupted = True
        finally:
            results.close()  # an interrupted run's workers stop here
            bar.close()
    if summary.interrupted:
        reported = {r.out for r in summary.results}
        left = [(v, o) for v, o in todo if str(o) not in reported]
        summary.results += [_unreported(v, o) for v, o in left]
        for folder in sorted({o.parent for _, o in left}):
            remove_stale_temps(folder)  # those of workers killed after the grace time
    summary.seconds = time.perf_counter() - t0
    return summary


def _unreported(video: Path, out: Path) -> TaskResult:
    """A task whose result did not come back before the stop: "done" where it finished
    its output meanwhile (frames as its sidecar records them), else "left"."""
    if is_complete(out):
        frames = json.loads(sidecar_path(out).read_text()).get("frames", 0)
        return TaskResult(str(video), str(out), "done", frames=int(frames))
    return TaskResult(str(video), str(out), "left")


def _dispatch(todo, process, jobs, scheduler):
    if not todo:
        return
    if scheduler is not None:
        from distributed import Client
        from distributed import as_completed as dask_completed

        with Client(scheduler) as client:
            futures = [client.submit(_run_one, process, v, o, pure=False) for v, o in todo]
            for fut in dask_completed(futures):
                yield fut.result()
        return
    if jobs <= 1:
        for v, o in todo:
            yield _run_one(process, v, o)
        return
    calls = [(process, v, o) for v, o in todo]
    with _opencv_one_thread():
        yield from run_in_processes(_run_one, calls, min(jobs, len(todo)))


@contextlib.contextmanager
def _opencv_one_thread():
    """OpenCV on one thread in this process while its workers are forked and run.

    OpenCV's thread pool does not survive a fork: in a worker forked while the pool's
    threads ran (this process used OpenCV before, as a notebook or a test session does),
    cv2.setNumThreads waits forever for threads that exist only here.
    """
    import cv2

    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    cv2.getNumThreads()  # the pool is rebuilt on its next use: here, not in a worker
    try:
        yield
    finally:
        cv2.setNumThreads(threads)


@dataclass(frozen=True)
class BatchTask:
    """The front end on one video, as a picklable campaign task.

    Writes the signal table (CSV, or Parquet when ``out`` ends in .parquet),
    its rest check image and its sidecar, then marks the output complete in the sidecar with its
    size, digest, decoder and timings.
    """

    sensor: object  # camwhisker.sensor.file.Sensor
    options: object = None  # camwhisker.vision.tracker.FrontEndOptions
    calibration_id: str | None = None
    rest_index: int = 0
    fps: float | None = None
    springs: object = None  # camwhisker.sensor.springs.Stiffness: adds the force columns

    def __call__(self, video: Path, out: Path) -> dict:
        from camwhisker.run.overlay import rest_check_path

        out = Path(out)
        try:
            return self._run(Path(video), out)
        except BaseException as exc:
            # Interrupted (Ctrl-C, a worker told to stop) between the table and the sidecar
            # that completes it: what this call wrote goes, so a stop leaves whole outputs.
            if not isinstance(exc, Exception) and not is_complete(out):
                for p in (out, sidecar_path(out), rest_check_path(out)):
                    p.unlink(missing_ok=True)
            raise

    def _run(self, video: Path, out: Path) -> dict:
        from camwhisker.run.batch import run_batch
        from camwhisker.run.overlay import rest_check_path

        parquet = out.suffix.lower() == ".parquet"
        # Parquet is converted from the CSV, written first under a hidden name.
        table = out.with_name(f".{out.stem}.partial.csv") if parquet else out
        t0 = time.perf_counter()
        try:
            report = run_batch(
                video,
                self.sensor,
                table,
                self.options,
                self.rest_index,
                self.fps,
                progress=False,
                decode_threads=1,  # one core per task, decoding included
                springs=self.springs,
            )
            seconds = time.perf_counter() - t0
            meta = json.loads(report.sidecar.read_text())
            if parquet:
                _csv_to_parquet(table, out)
                if report.rest_check is not None:
                    check = durable_replace(report.rest_check, rest_check_path(out))
                    meta["rest_check"] = check.name
        finally:
            if parquet:  # the hidden CSV and its companions, used or interrupted
                for p in (table, sidecar_path(table), rest_check_path(table)):
                    p.unlink(missing_ok=True)
        meta.update(
            calibration_id=self.calibration_id,
            frames_decoded=report.frames,
            timings={"seconds": seconds, "frames_per_s": report.frames / seconds},
        )
        write_sidecar(out, meta, complete=not report.problems)
        return {"frames": report.frames, "error": "; ".join(report.problems)}


def _csv_to_parquet(csv_path: Path, out: Path) -> None:
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    table = pacsv.read_csv(csv_path)
    with atomic_path(out) as tmp:
        pq.write_table(table, tmp)
