"""Training: a model of one kind (:data:`KINDS`) fitted, chosen on validation, refitted.

- ``knn`` (:mod:`~camwhisker.learn.knn`): the training windows stored; the neighbour count
  chosen on the validation windows.
- ``conv`` (:mod:`~camwhisker.learn.net`): minibatches of windows, Adam, the epoch with the
  lowest validation loss kept.

:func:`learn` splits the tables (:func:`~camwhisker.learn.series.split_tables`), trains,
and then fits the final model on every table with the setting validation chose (the
neighbour count; the number of epochs), so no recording is left out of the model.

The conv's loss is the mean squared error of the encoded targets: normalised scalars, and per
angle its (sin, cos), whose squared distance 2 - 2 cos(error) is periodic, so 179 deg and
-179 deg are 2 deg apart.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from camwhisker.learn.knn import WindowKnn
from camwhisker.learn.net import build_net, conv_dilations, import_torch
from camwhisker.learn.series import (
    Columns,
    LearnError,
    Normalisation,
    Series,
    decode_targets,
    encode_targets,
    fit_normalisation,
    gather_windows,
    split_tables,
    window_ends,
)

__all__ = ["KINDS", "TrainOptions", "Trained", "train", "refit", "learn", "predict_encoded",
           "predict_raw", "target_errors"]  # fmt: skip

#: The model kinds, the default first (chosen by ``camwhisker dev learn-bench``).
KINDS = ("knn", "conv")

#: Windows per forward pass when predicting (memory: 4096 x 40 x C floats).
PREDICT_BATCH = 4096


@dataclass(frozen=True)
class TrainOptions:
    kind: str = KINDS[0]
    #: How validation windows are held out (:data:`~camwhisker.learn.series.SPLITS`).
    validation: str = "time"
    #: The final model fitted on every table (training and validation) after the choice.
    refit: bool = True
    #: The conv's architecture and optimisation (the knn kind has no other setting).
    arch: dict = field(default_factory=lambda: {"kind": "conv", "hidden": 32})
    epochs: int = 20
    batch: int = 256
    #: Windows drawn per epoch (all when fewer): bounds an epoch's time on long recordings.
    samples_per_epoch: int = 200_000
    #: Windows of the validation tables scored per epoch (evenly spaced when more).
    validation_samples: int = 50_000
    lr: float = 2e-3
    #: Epochs without a better validation loss before training stops.
    patience: int = 6
    seed: int = 0


@dataclass
class Trained:
    net: object
    norm: Normalisation
    #: The architecture as built (the convolution's dilations fitted to the window).
    arch: dict
    summary: dict


def _stack(series: list[Series], columns: Columns, norm: Normalisation, window: int):
    y = np.concatenate([encode_targets(s.targets, columns, norm) for s in series])
    ends = window_ends([s.inputs.shape[0] for s in series], window)
    return _normalised(series, norm), y, ends


def predict_encoded(net, x: np.ndarray, ends: np.ndarray, window: int) -> np.ndarray:
    """The net's encoded outputs shape (B, n_encoded) for the windows ending at ``ends``."""
    torch = import_torch()
    net.eval()
    out = []
    with torch.inference_mode():
        for i in range(0, ends.size, PREDICT_BATCH):
            w = gather_windows(x, ends[i : i + PREDICT_BATCH], window)
            out.append(net(torch.from_numpy(w)).numpy())
    return np.concatenate(out) if out else np.zeros((0, 0), np.float32)


def target_errors(pred: np.ndarray, truth: np.ndarray, columns: Columns) -> dict:
    """Per target: RMSE (scalars, their unit) or RMS and mean absolute error on the circle
    (angles, degrees); ``pred`` and ``truth`` raw, shape (N, n_targets)."""
    out = {}
    for j, name in enumerate(columns.all_targets):
        d = pred[:, j] - truth[:, j]
        if name in columns.angle_targets:
            d = (d + 180.0) % 360.0 - 180.0
            out[name] = {"rms_deg": float(np.sqrt(np.mean(d**2))),
                         "mae_deg": float(np.mean(np.abs(d)))}  # fmt: skip
        else:
            out[name] = {"rmse": float(np.sqrt(np.mean(d**2)))}
    return out


def predict_raw(est, x: np.ndarray, ends: np.ndarray, window: int, columns: Columns,
                norm: Normalisation) -> np.ndarray:  # fmt: skip
    """Raw targets shape (B, n_targets) (angles in degrees) of a model of any kind for the
    windows of normalised inputs ``x`` ending at ``ends``."""
    if isinstance(est, WindowKnn):
        return est.predict(x, ends)
    return decode_targets(predict_encoded(est, x, ends, window), columns, norm)


def _summary(training, validation, x, vx, vends, vtruth, pred, columns, t0, opts) -> dict:
    return {"training_tables": sorted({str(s.path) for s in training}),
            "validation_tables": sorted({str(s.path) for s in validation}),
            "validation": opts.validation,
            "training_rows": int(x.shape[0]), "validation_rows": int(vx.shape[0]),
            "validation_windows_scored": int(vends.size),
            "validation_errors": target_errors(pred, vtruth[vends], columns),
            "train_s": time.perf_counter() - t0, "options": opts.__dict__}  # fmt: skip


def _validation_ends(vx_len: list[int], window: int, most: int) -> np.ndarray:
    vends = window_ends(vx_len, window)
    if vends.size > most:
        vends = vends[np.linspace(0, vends.size - 1, most).astype(np.int64)]
    return vends


def _train_knn(training, validation, columns, window, opts, k=None) -> Trained:
    t0 = time.perf_counter()
    norm = fit_normalisation(training, columns)
    x = _normalised(training, norm)
    knn = WindowKnn(x, np.concatenate([s.targets for s in training]),
                    [s.inputs.shape[0] for s in training], window, len(columns.angle_targets))
    if k is not None:  # refitted: the count validation chose
        knn.k = k
        return Trained(knn, norm, {"kind": "knn", "k": k}, {"training_rows": int(x.shape[0])})
    vx = _normalised(validation, norm)
    vends = _validation_ends([s.inputs.shape[0] for s in validation], window,
                             opts.validation_samples)  # fmt: skip
    vtruth = np.concatenate([s.targets for s in validation])
    scores = knn.choose_k(vx, vends, vtruth[vends], columns, norm.target_std)
    summary = _summary(training, validation, x, vx, vends, vtruth, knn.predict(vx, vends),
                       columns, t0, opts)  # fmt: skip
    summary.update({"k": knn.k, "validation_score_per_k": {str(k): v for k, v in scores.items()}})
    return Trained(knn, norm, {"kind": "knn", "k": knn.k}, summary)


def _normalised(series: list[Series], norm: Normalisation) -> np.ndarray:
    x = np.concatenate([(s.inputs - norm.input_mean) / norm.input_std for s in series])
    return x.astype(np.float32)


def train(training: list[Series], validation: list[Series], columns: Columns, window: int,
          opts: TrainOptions = TrainOptions(), progress: bool = True,
          net=None) -> Trained:  # fmt: skip
    """Fit a model of ``opts.kind`` on the training tables, its setting chosen on the
    validation tables (knn: the neighbour count; conv: the epoch). ``net``: a fresh torch
    module to train instead of ``opts.arch``'s (a benchmark's)."""
    if opts.kind not in KINDS:
        raise LearnError(f"unknown model kind {opts.kind!r} (known: {', '.join(KINDS)})")
    if opts.kind == "knn" and net is None:
        return _train_knn(training, validation, columns, window, opts)
    return _train_conv(training, validation, columns, window, opts, progress, net)


def refit(trained: Trained, series: list[Series], columns: Columns, window: int,
          opts: TrainOptions = TrainOptions(), progress: bool = True) -> Trained:
    """The final model: ``trained``'s kind and chosen setting fitted on every table in
    ``series``; its summary is ``trained``'s (the validation scores of the choice) with
    the final rows and time added."""
    t0 = time.perf_counter()
    if trained.arch["kind"] == "knn":
        final = _train_knn(series, [], columns, window, opts, k=trained.arch["k"])
    else:
        final = _train_conv(series, [], columns, window, opts, progress,
                            epochs=trained.summary["best_epoch"])  # fmt: skip
    summary = {**trained.summary, "final_tables": len(series),
               "final_training_rows": final.summary["training_rows"],
               "final_s": time.perf_counter() - t0}  # fmt: skip
    return Trained(final.net, final.norm, final.arch, summary)


def learn(series: list[Series], columns: Columns, window: int,
          opts: TrainOptions = TrainOptions(), progress: bool = True) -> Trained:  # fmt: skip
    """Split (``opts.validation``), train, and (``opts.refit``) refit on every table."""
    training, validation = split_tables(series, window, opts.validation)
    trained = train(training, validation, columns, window, opts, progress)
    return refit(trained, series, columns, window, opts, progress) if opts.refit else trained


def _train_conv(training, validation, columns, window, opts, progress, net=None,
                epochs=None) -> Trained:  # fmt: skip
    """The conv's loop; with ``epochs`` (a refit: no validation) that many epochs, the last
    kept."""
    torch = import_torch()
    torch.manual_seed(opts.seed)
    rng = np.random.default_rng(opts.seed)
    t0 = time.perf_counter()
    norm = fit_normalisation(training, columns)
    x, y, ends = _stack(training, columns, norm, window)
    arch = {**opts.arch, "dilations": conv_dilations(window)}
    if net is None:
        net = build_net(arch, len(columns.inputs), columns.n_encoded)
    optim = torch.optim.Adam(net.parameters(), lr=opts.lr)
    per_epoch = min(opts.samples_per_epoch, ends.size)
    n_epochs = opts.epochs if epochs is None else epochs
    if epochs is None:
        vx, vy, _ = _stack(validation, columns, norm, window)
        vends = _validation_ends([s.inputs.shape[0] for s in validation], window,
                                 opts.validation_samples)  # fmt: skip
    best = (math.inf, 0, None)
    history = []
    bar = tqdm(total=n_epochs * per_epoch, unit="win", unit_scale=True, desc="learn",
               disable=not progress, mininterval=1.0)  # fmt: skip
    for epoch in range(1, n_epochs + 1):
        net.train()
        order = rng.permutation(ends.size)[:per_epoch]
        total = 0.0
        for i in range(0, per_epoch, opts.batch):
            idx = ends[order[i : i + opts.batch]]
            xb = torch.from_numpy(gather_windows(x, idx, window))
            loss = torch.mean((net(xb) - torch.from_numpy(y[idx])) ** 2)
            optim.zero_grad()
            loss.backward()
            optim.step()
            total += float(loss.detach()) * idx.size
            bar.update(idx.size)
        if epochs is not None:
            history.append({"epoch": epoch, "train_loss": total / per_epoch})
            continue
        val = float(np.mean((predict_encoded(net, vx, vends, window) - vy[vends]) ** 2))
        history.append({"epoch": epoch, "train_loss": total / per_epoch, "val_loss": val})
        bar.set_postfix(epoch=epoch, train=f"{total / per_epoch:.4f}", val=f"{val:.4f}")
        if val < best[0]:
            best = (val, epoch, {k: v.detach().clone() for k, v in net.state_dict().items()})
        elif epoch - best[1] >= opts.patience:
            break
    bar.close()
    if epochs is not None:
        return Trained(net, norm, arch, {"training_rows": int(x.shape[0]), "history": history})
    net.load_state_dict(best[2])
    vtruth = np.concatenate([s.targets for s in validation])
    pred = decode_targets(predict_encoded(net, vx, vends, window), columns, norm)
    summary = _summary(training, validation, x, vx, vends, vtruth, pred, columns, t0, opts)
    summary.update({"epochs_run": len(history), "best_epoch": best[1],
                    "best_val_loss": best[0], "history": history})  # fmt: skip
    return Trained(net, norm, arch, summary)
