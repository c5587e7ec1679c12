"""The nearest-neighbour kind: a window's summary features -> its nearest training windows.

Each window of normalised inputs is summarised per input column by its last value, mean,
least-squares slope, minimum and maximum, and over all columns by its roughness, the mean
absolute step between rows (:func:`window_features`); the features are standardised over
the training windows, then weighted (:data:`WEIGHTS`).
A window's estimate is taken from its ``k`` nearest training windows (Euclidean, a k-d
tree): per scalar target their median (robust, and a value the training data hold), per
angle target the direction of their unit vectors' mean. ``k`` is chosen on the validation
windows from :data:`K_CHOICES`.

The model stores the training rows themselves (normalised inputs, raw targets, each
table's length), not the features: the features are rebuilt from them on loading.
"""

from __future__ import annotations

import numpy as np

from camwhisker.learn.series import Columns, gather_windows, window_ends

__all__ = ["K_CHOICES", "WEIGHTS", "window_features", "feature_weights", "WindowKnn",
           "encoded_distance"]

#: Neighbour counts tried on the validation windows; the best is kept.
K_CHOICES = (5, 10, 20, 40)
#: Weight of each feature group after standardisation, chosen on a real whisker's validation
#: windows (docs/learn.md): slopes 0.5 (beat 0.25 and 1); roughness 0.4 (beat 0.25-1; it
#: tells a flat window at rest from one held in contact, which levels alone confuse).
WEIGHTS = {"last": 1.0, "mean": 1.0, "slope": 0.5, "min": 1.0, "max": 1.0, "roughness": 0.4}
#: Windows per step of features and queries (memory: CHUNK x window x C floats).
CHUNK = 65_536


def window_features(x: np.ndarray, ends: np.ndarray, window: int) -> np.ndarray:
    """Features shape (B, 5 C + 1) of the windows of rows ``x`` shape (N, C) ending at
    ``ends``, in :data:`WEIGHTS`' order: per column the last value, mean, slope per row
    (least squares), minimum and maximum; then the roughness, the mean absolute step
    between rows over all columns (0 for a one-row window). Computed :data:`CHUNK` windows
    at a time (memory: CHUNK x window x C floats)."""
    t = np.arange(window) - (window - 1) / 2.0
    out = np.empty((ends.size, 5 * x.shape[1] + 1))
    for i in range(0, ends.size, CHUNK):
        w = gather_windows(x, ends[i : i + CHUNK], window).astype(np.float64)
        slope = np.einsum("bwc,w->bc", w, t) / max(float(t @ t), 1.0)
        rough = np.abs(np.diff(w, axis=1)).mean(axis=(1, 2)) if window > 1 else w[:, 0, 0] * 0
        out[i : i + CHUNK] = np.concatenate([w[:, -1], w.mean(axis=1), slope, w.min(axis=1),
                                             w.max(axis=1), rough[:, None]], axis=1)  # fmt: skip
    return out


def feature_weights(n_inputs: int) -> np.ndarray:
    """:data:`WEIGHTS` per feature of :func:`window_features`, shape (5 n_inputs + 1,)."""
    return np.array([v for k, v in WEIGHTS.items()
                     for _ in range(1 if k == "roughness" else n_inputs)])  # fmt: skip


def encoded_distance(pred: np.ndarray, truth: np.ndarray, columns: Columns,
                     target_std: np.ndarray) -> np.ndarray:  # fmt: skip
    """Per row the Euclidean distance shape (N,) between raw targets in the encoded space
    (scalars over their std, angles as unit vectors): one score across units."""
    k = len(columns.targets)
    d2 = (((pred[:, :k] - truth[:, :k]) / target_std) ** 2).sum(axis=1)
    da = np.radians(pred[:, k:] - truth[:, k:])
    d2 += (2.0 - 2.0 * np.cos(da)).sum(axis=1)
    return np.sqrt(d2)


class WindowKnn:
    """k nearest windows over the training tables' rows (normalised inputs ``rows`` shape
    (N, C), raw targets shape (N, n_targets), ``lengths`` each table's rows)."""

    def __init__(self, rows: np.ndarray, targets: np.ndarray, lengths, window: int,
                 n_angles: int, k: int = 10):  # fmt: skip
        from scipy.spatial import cKDTree

        self.rows = np.asarray(rows, np.float32)
        self.targets = np.asarray(targets, np.float32)
        self.lengths = np.asarray(lengths, np.int64)
        self.window, self.n_angles, self.k = int(window), int(n_angles), int(k)
        ends = window_ends(list(self.lengths), self.window)
        f = window_features(self.rows, ends, self.window)
        self.mean = f.mean(axis=0)
        std = f.std(axis=0)
        # a feature constant over the training windows tells them apart by nothing: weight 0
        self.scale = np.where(std > 0, 1.0 / np.where(std > 0, std, 1.0), 0.0)
        self.scale *= feature_weights(self.rows.shape[1])
        self.end_targets = self.targets[ends]
        self.tree = cKDTree((f - self.mean) * self.scale)

    def state(self) -> dict[str, np.ndarray]:
        """The arrays the model directory stores (weights.npz)."""
        return {"rows": self.rows, "targets": self.targets, "lengths": self.lengths}

    def neighbours(self, x: np.ndarray, ends: np.ndarray, k: int) -> np.ndarray:
        """Indices shape (B, k) into the training windows of the ``k`` nearest of each
        window of ``x`` (normalised inputs) ending at ``ends``."""
        k = min(k, self.tree.n)  # fewer training windows than k: all of them
        out = []
        for i in range(0, ends.size, CHUNK):
            f = (window_features(x, ends[i : i + CHUNK], self.window) - self.mean) * self.scale
            out.append(self.tree.query(f, k=k)[1].reshape(-1, k))
        return np.concatenate(out) if out else np.zeros((0, k), np.int64)

    def estimate(self, idx: np.ndarray) -> np.ndarray:
        """Raw targets shape (B, n_targets) from neighbour indices shape (B, k): scalars
        their median, angles (deg) the direction of their unit vectors' mean."""
        t = self.end_targets[idx].astype(np.float64)
        n_scal = t.shape[2] - self.n_angles
        ang = np.radians(t[:, :, n_scal:])
        deg = np.degrees(np.arctan2(np.sin(ang).mean(axis=1), np.cos(ang).mean(axis=1)))
        return np.concatenate([np.median(t[:, :, :n_scal], axis=1), deg], axis=1)

    def predict(self, x: np.ndarray, ends: np.ndarray) -> np.ndarray:
        """Raw targets shape (B, n_targets) for the windows of ``x`` ending at ``ends``."""
        return self.estimate(self.neighbours(x, ends, self.k))

    def choose_k(self, x: np.ndarray, ends: np.ndarray, truth: np.ndarray, columns: Columns,
                 target_std: np.ndarray) -> dict[int, float]:  # fmt: skip
        """Set ``k`` to the one of :data:`K_CHOICES` with the least mean
        :func:`encoded_distance` on the windows of ``x`` ending at ``ends`` (raw ``truth``
        per window; a k over the training windows' count tried as that count); returns
        that score per k."""
        choices = sorted({min(k, self.tree.n) for k in K_CHOICES})
        idx = self.neighbours(x, ends, choices[-1])
        scores = {k: float(encoded_distance(self.estimate(idx[:, :k]), truth, columns,
                                            target_std).mean()) for k in choices}  # fmt: skip
        self.k = min(scores, key=scores.get)
        return scores
