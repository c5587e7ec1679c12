"""Training: minibatches of windows, Adam, the epoch with the lowest validation loss kept.

The loss is the mean squared error of the encoded targets: normalised scalars, and per
angle its (sin, cos), whose squared distance 2 - 2 cos(error) is periodic, so 179 deg and
-179 deg are 2 deg apart.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from camwhisker.learn.net import build_net, conv_dilations, import_torch
from camwhisker.learn.series import (
    Columns,
    Normalisation,
    Series,
    decode_targets,
    encode_targets,
    fit_normalisation,
    gather_windows,
    window_ends,
)

__all__ = ["TrainOptions", "Trained", "train", "predict_encoded", "target_errors"]

#: Windows per forward pass when predicting (memory: 4096 x 40 x C floats).
PREDICT_BATCH = 4096


@dataclass(frozen=True)
class TrainOptions:
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
    x = np.concatenate([(s.inputs - norm.input_mean) / norm.input_std for s in series])
    y = np.concatenate([encode_targets(s.targets, columns, norm) for s in series])
    ends = window_ends([s.inputs.shape[0] for s in series], window)
    return x.astype(np.float32), y, ends


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


def train(training: list[Series], validation: list[Series], columns: Columns, window: int,
          opts: TrainOptions = TrainOptions(), progress: bool = True,
          net=None) -> Trained:  # fmt: skip
    """Fit a net on the training tables; keep the epoch best on the validation tables.
    ``net``: a fresh torch module to train instead of ``opts.arch``'s (a benchmark's)."""
    torch = import_torch()
    torch.manual_seed(opts.seed)
    rng = np.random.default_rng(opts.seed)
    t0 = time.perf_counter()
    norm = fit_normalisation(training, columns)
    x, y, ends = _stack(training, columns, norm, window)
    vx, vy, vends = _stack(validation, columns, norm, window)
    if vends.size > opts.validation_samples:
        vends = vends[np.linspace(0, vends.size - 1, opts.validation_samples).astype(np.int64)]
    vtruth = np.concatenate([s.targets for s in validation])
    arch = {**opts.arch, "dilations": conv_dilations(window)}
    if net is None:
        net = build_net(arch, len(columns.inputs), columns.n_encoded)
    optim = torch.optim.Adam(net.parameters(), lr=opts.lr)
    per_epoch = min(opts.samples_per_epoch, ends.size)
    best = (math.inf, 0, None)
    history = []
    bar = tqdm(total=opts.epochs * per_epoch, unit="win", unit_scale=True, desc="learn",
               disable=not progress, mininterval=1.0)  # fmt: skip
    for epoch in range(1, opts.epochs + 1):
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
        val = float(np.mean((predict_encoded(net, vx, vends, window) - vy[vends]) ** 2))
        history.append({"epoch": epoch, "train_loss": total / per_epoch, "val_loss": val})
        bar.set_postfix(epoch=epoch, train=f"{total / per_epoch:.4f}", val=f"{val:.4f}")
        if val < best[0]:
            best = (val, epoch, {k: v.detach().clone() for k, v in net.state_dict().items()})
        elif epoch - best[1] >= opts.patience:
            break
    bar.close()
    net.load_state_dict(best[2])
    pred = decode_targets(predict_encoded(net, vx, vends, window), columns, norm)
    summary = {
        "training_tables": [str(s.path) for s in training],
        "validation_tables": [str(s.path) for s in validation],
        "training_rows": int(x.shape[0]), "validation_rows": int(vx.shape[0]),
        "validation_windows_scored": int(vends.size),
        "epochs_run": len(history), "best_epoch": best[1], "best_val_loss": best[0],
        "validation_errors": target_errors(pred, vtruth[vends], columns),
        "train_s": time.perf_counter() - t0, "options": opts.__dict__, "history": history,
    }
    return Trained(net, norm, arch, summary)

