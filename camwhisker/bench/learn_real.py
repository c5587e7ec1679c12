"""The learned estimator on a real whisker's recordings, with its authors' metric.

The data (not in the repository; its path is an argument): an npz of a three-barometer
whisker's recordings at 115 Hz, one per contact configuration (``signals`` (N, 3); labels
``R`` radial deflection in mm, ``H`` contact height in cm, ``O`` azimuth in deg; recording
k is rows ``offsets[k]:offsets[k + 1]``).

The time split: the first 80 % of each recording to learn (``learn``'s own validation and
final fit happen inside it), the last 20 % to score, windows inside each part. The
authors' metric (:func:`authors_metric`): R and H min-max normalised to 0-100 over the
scored rows, x = Rn cos O, y = Rn sin O, z = Hn, the mean Euclidean distance read as mm.
Beside ``learn``: the k-nearest-neighbour reference (:func:`reference_knn`) and the
authors' recurrent network's published score (:data:`PAPER_MM`, their own split).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from camwhisker.learn.knn import window_features
from camwhisker.learn.series import Columns, LearnError, Series, window_ends

__all__ = ["COLUMNS", "WINDOW", "PAPER_MM", "load_recordings", "time_split", "authors_metric",
           "reference_knn", "run_real", "format_real"]  # fmt: skip

COLUMNS = Columns(("s1", "s2", "s3"), ("r_mm", "h_cm"), ("azimuth_deg",))
WINDOW = 40
#: The authors' recurrent network (RMN) on their test split, mean 3-D error (mm).
PAPER_MM = 9.18
LEARN_SHARE = 0.8
KEYS = ("signals", "R", "H", "O", "offsets")


def load_recordings(path: str | Path) -> list[Series]:
    """One table per recording: inputs the three channels, targets (R, H, O)."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as npz:
            missing = [k for k in KEYS if k not in npz.files]
            if missing:
                raise LearnError(f"{path}: missing key(s) {', '.join(missing)} (needs "
                                 f"{', '.join(KEYS)})")  # fmt: skip
            d = {k: npz[k] for k in KEYS}
    except (OSError, ValueError) as exc:
        raise LearnError(f"{path}: cannot read the recordings ({exc})") from None
    y = np.stack([d["R"], d["H"], d["O"]], axis=1).astype(np.float64)
    x = np.asarray(d["signals"], np.float64)
    off = np.asarray(d["offsets"], np.int64)
    return [Series(f"{path.name}[{a}:{b}]", x[a:b], y[a:b]) for a, b in zip(off, off[1:],
                                                                           strict=False)]


def time_split(recordings: list[Series], share: float = LEARN_SHARE):
    """(learn, score): each recording's first ``share`` of rows and the rest."""
    learn, score = [], []
    for s in recordings:
        c = int(round(s.inputs.shape[0] * share))
        learn.append(Series(s.path, s.inputs[:c], s.targets[:c]))
        score.append(Series(s.path, s.inputs[c:], s.targets[c:]))
    return learn, score


def authors_metric(pred: np.ndarray, truth: np.ndarray) -> dict:
    """The authors' score of raw (R mm, H cm, O deg) rows shape (N, 3): mean and median
    3-D error and MAE of Rn and Hn (0-100 over ``truth``'s range, read as mm) and of the
    azimuth (deg, on the circle)."""
    lo, hi = truth[:, :2].min(axis=0), truth[:, :2].max(axis=0)

    def xyz(v):
        n = (v[:, :2] - lo) / (hi - lo) * 100.0
        o = np.radians(v[:, 2])
        return np.stack([n[:, 0] * np.cos(o), n[:, 0] * np.sin(o), n[:, 1]], axis=1)

    e = np.linalg.norm(xyz(pred) - xyz(truth), axis=1)
    mae = np.abs(pred[:, :2] - truth[:, :2]).mean(axis=0) / (hi - lo) * 100.0
    daz = (pred[:, 2] - truth[:, 2] + 180.0) % 360.0 - 180.0
    return {"mean_mm": float(e.mean()), "median_mm": float(np.median(e)),
            "r_mm": float(mae[0]), "h_mm": float(mae[1]),
            "azimuth_deg": float(np.abs(daz).mean())}  # fmt: skip


def _stack(series: list[Series]):
    ends = window_ends([s.inputs.shape[0] for s in series], WINDOW)
    return (np.concatenate([s.inputs for s in series]), np.concatenate([s.targets for s in series]),
            ends)  # fmt: skip


def reference_knn(learn: list[Series], score: list[Series], k: int = 5) -> np.ndarray:
    """The reference: k-nearest-neighbour regression (k = 5, uniform) on standardised window
    features (last value, mean, slope, minimum, maximum per channel: those of
    :func:`~camwhisker.learn.knn.window_features` without the roughness); targets the
    neighbours' mean, the azimuth their unit vectors' mean. Raw (R, H, O) per window."""
    from scipy.spatial import cKDTree

    x, y, ends = _stack(learn)
    sx, _, sends = _stack(score)
    f = window_features(x, ends, WINDOW)[:, :-1]
    mean, std = f.mean(axis=0), f.std(axis=0)
    sf = window_features(sx, sends, WINDOW)[:, :-1]
    idx = cKDTree((f - mean) / std).query((sf - mean) / std, k=k)[1]
    t = y[ends][idx]
    o = np.radians(t[:, :, 2])
    az = np.degrees(np.arctan2(np.sin(o).mean(axis=1), np.cos(o).mean(axis=1)))
    return np.concatenate([t[:, :, :2].mean(axis=1), az[:, None]], axis=1)


def _batch1_ms(model, x: np.ndarray, ends: np.ndarray, calls: int = 200) -> float:
    """Least ms of one window's estimate at batch 1 (after 20 warm-up calls)."""
    from camwhisker.learn.train import predict_raw

    times = []
    for e in ends[: calls + 20]:
        t = time.perf_counter()
        predict_raw(model.net, x, e[None], WINDOW, COLUMNS, model.norm)
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.min(times[20:]))


def run_real(path, kinds=("knn",), progress: bool = False) -> dict:
    """Per model (``learn --kind`` for each of ``kinds``, then the reference): the authors'
    metric on the time split, training and scoring time, batch-1 ms per window."""
    from camwhisker.learn.train import TrainOptions, learn, predict_raw

    learn_part, score = time_split(load_recordings(path))
    sx, struth, sends = _stack(score)
    out = {}
    for kind in kinds:
        t0 = time.perf_counter()
        trained = learn(learn_part, COLUMNS, WINDOW, TrainOptions(kind=kind), progress=progress)
        train_s = time.perf_counter() - t0
        x = ((sx - trained.norm.input_mean) / trained.norm.input_std).astype(np.float32)
        t0 = time.perf_counter()
        pred = predict_raw(trained.net, x, sends, WINDOW, COLUMNS, trained.norm)
        chose = (f"k {trained.arch['k']}" if kind == "knn"
                 else f"epoch {trained.summary['best_epoch']}")  # fmt: skip
        out[f"learn --kind {kind} ({chose})"] = {
            **authors_metric(pred, struth[sends]), "train_s": train_s,
            "score_s": time.perf_counter() - t0, "batch1_ms": _batch1_ms(trained, x, sends)}
    t0 = time.perf_counter()
    pred = reference_knn(learn_part, score)
    out["kNN reference (k 5, mean)"] = {**authors_metric(pred, struth[sends]), "train_s": 0.0,
                                         "score_s": time.perf_counter() - t0,
                                         "batch1_ms": np.nan}  # fmt: skip
    out["_windows"] = (int(sum(s.inputs.shape[0] - WINDOW + 1 for s in learn_part)),
                       int(sends.size), len(score))  # fmt: skip
    return out


def format_real(result: dict) -> str:
    """A Markdown table of :func:`run_real`'s result."""
    n_learn, n_score, n_rec = result["_windows"]
    lines = ["| model | mean 3-D mm | median mm | MAE r mm | MAE h mm | MAE azimuth deg | "
             "train s | score s | batch 1 ms |", "|---" * 9 + "|"]
    for name, m in result.items():
        if name.startswith("_"):
            continue
        lines.append(f"| {name} | {m['mean_mm']:.2f} | {m['median_mm']:.2f} | {m['r_mm']:.2f} "
                     f"| {m['h_mm']:.2f} | {m['azimuth_deg']:.2f} | {m['train_s']:.0f} | "
                     f"{m['score_s']:.0f} | {m['batch1_ms']:.3f} |")
    lines.append(f"| authors' RMN (paper, their split) | {PAPER_MM:.2f} | | | | | | | |")
    lines += ["", f"Time split of {n_rec} recordings: {n_learn:,} windows (first 80 % of each) "
              f"to learn, {n_score:,} (last 20 %) scored; window {WINDOW}."]
    return "\n".join(lines)
