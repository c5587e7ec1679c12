"""The learned estimator (camwhisker learn): architecture, training time, inference speed.

The task stands in for a base-sensing whisker's recorded dataset (three base
channels at 115 Hz; contact radius, height and azimuth): a cantilever pushed at a point
``r_mm`` out and ``h_mm`` up, in direction ``azimuth_deg``, by a base moving at a
constant speed into and out of it. At the base, the moment is ``delta / r**2`` in the
azimuth's direction (``mx``, ``my``) and the axial force ``delta * h / r**3``, with
``delta`` the push; one instant holds three unknowns (delta, r, h) in two magnitudes, and
the moment's rate (speed / r**2) gives r: the estimate needs the window's history.

``camwhisker dev learn-bench compare [--rows N]``: a GRU, a 1-D convolution and a
ridge on random window features, trained on the same tables, scored on other seeds' tables.
``camwhisker dev learn-bench scale [--rows 1500000]``: ``learn --kind conv``'s defaults on
1.5 M rows of 3 channels, window 40: training time, inference per sample at batch 1 and
batched.
``camwhisker dev learn-bench sensor [--seed 0] [--kind conv] [--out DIR]``: on our sensor's
simulated runs, trained on the calibration runs of a seed, against GM, MF and fused on runs
of seed + 1 (:mod:`camwhisker.bench.learn_sensor`).
``camwhisker dev learn-bench real --data PATH.npz [--kind knn] [--kind conv]``: on a real
whisker's recordings, ``learn`` and a kNN reference with the authors' metric on the time
split (:mod:`camwhisker.bench.learn_real`).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from camwhisker.bench.learn_sensor import SensorOptions, format_sensor, run_sensor
from camwhisker.learn.sensor import SENSOR_INPUTS, sensor_columns
from camwhisker.learn.series import (
    Columns,
    Series,
    decode_targets,
    encode_targets,
    gather_windows,
    split_by_table,
    window_ends,
)
from camwhisker.learn.train import KINDS, target_errors

__all__ = ["COLUMNS", "WINDOW", "RATE_HZ", "whisker_tables", "window_gru", "RidgeWindows",
           "main"]

COLUMNS = Columns(("mx", "my", "fz"), ("r_mm", "h_mm"), ("azimuth_deg",))
WINDOW = 40
RATE_HZ = 115.0
#: Base speed (mm/s): one robot's sweeps, so the moment's rate carries r.
SPEED_MM_S = 20.0
#: Channel noise, as a share of each channel's typical magnitude.
NOISE = 0.01
ROWS_PER_TABLE = 50_000


def whisker_tables(n_rows: int, seed: int, rows_per_table: int = ROWS_PER_TABLE) -> list[Series]:
    """Tables of contact episodes (push in, hold, release) totalling ``n_rows`` rows."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(int(np.ceil(n_rows / rows_per_table))):
        n = min(rows_per_table, n_rows - k * rows_per_table)
        out.append(_one_table(n, rng, f"whisker-seed{seed}-{k}"))
    return out


def _one_table(n: int, rng, name: str) -> Series:
    delta, r, h, az = (np.empty(n) for _ in range(4))
    i = 0
    step = SPEED_MM_S / RATE_HZ
    while i < n:
        push = rng.uniform(1.0, 6.0)  # mm of base travel into the contact
        ramp = max(2, int(push / step))
        hold = int(rng.integers(10, 60))
        prof = np.concatenate([np.arange(1, ramp + 1) * step, np.full(hold, ramp * step),
                               np.arange(ramp, 0, -1) * step])  # fmt: skip
        m = min(prof.size, n - i)
        delta[i : i + m] = prof[:m]
        r[i : i + m], h[i : i + m] = rng.uniform(20.0, 80.0), rng.uniform(0.0, 40.0)
        az[i : i + m] = rng.uniform(-180.0, 180.0)
        i += m
    moment = 1e3 * delta / r**2
    a = np.radians(az)
    x = np.stack([moment * np.cos(a), moment * np.sin(a), 1e4 * delta * h / r**3], axis=1)
    x += NOISE * x.std(axis=0) * rng.standard_normal(x.shape)
    return Series(name, x, np.stack([r, h, az], axis=1))


def _stack(series: list[Series], norm) -> tuple[np.ndarray, np.ndarray]:
    x = np.concatenate([(s.inputs - norm.input_mean) / norm.input_std for s in series])
    return x.astype(np.float32), window_ends([s.inputs.shape[0] for s in series], WINDOW)


def window_gru(n_inputs: int, n_out: int, hidden: int = 32):
    """The recurrent comparator: a GRU over the window, a linear layer on its last state."""
    import torch

    class WindowGRU(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.rnn = torch.nn.GRU(n_inputs, hidden, batch_first=True)
            self.head = torch.nn.Linear(hidden, n_out)

        def forward(self, x):
            _, h = self.rnn(x)
            return self.head(h[-1])

    return WindowGRU()


class RidgeWindows:
    """The non-neural comparator: ridge regression on the flattened window and on random
    Fourier features of it (an approximate Gaussian-kernel ridge), solved in closed form."""

    def __init__(self, n_inputs: int, n_features: int = 1024, lam: float = 1e-3, seed: int = 0):
        rng = np.random.default_rng(seed)
        d = WINDOW * n_inputs
        self.proj = (rng.standard_normal((d, n_features)) / np.sqrt(d)).astype(np.float32)
        self.phase = rng.uniform(0, 2 * np.pi, n_features).astype(np.float32)
        self.lam, self.coef = lam, None

    def features(self, w: np.ndarray) -> np.ndarray:
        flat = w.reshape(w.shape[0], -1)
        return np.concatenate([flat, np.cos(flat @ self.proj + self.phase),
                               np.ones((flat.shape[0], 1), np.float32)], axis=1)  # fmt: skip

    def fit(self, x, y, ends, chunk: int = 8192):
        a = b = 0.0
        for i in range(0, ends.size, chunk):
            f = self.features(gather_windows(x, ends[i : i + chunk], WINDOW)).astype(np.float64)
            a = a + f.T @ f
            b = b + f.T @ y[ends[i : i + chunk]]
        a = a + self.lam * ends.size * np.eye(a.shape[0])
        self.coef = np.linalg.solve(a, b).astype(np.float32)
        return self

    def __call__(self, w: np.ndarray) -> np.ndarray:
        return self.features(w) @ self.coef


def _predict(model, x, ends) -> np.ndarray:
    if isinstance(model, RidgeWindows):
        return np.concatenate([model(gather_windows(x, ends[i : i + 4096], WINDOW))
                               for i in range(0, ends.size, 4096)])  # fmt: skip
    from camwhisker.learn.train import predict_encoded

    return predict_encoded(model, x, ends, WINDOW)


def _speed(model, x, ends) -> tuple[float, float]:
    """(ms per sample at batch 1, least over 200 calls after 20 warm-up calls; samples/s
    batched, 4096 per call, over up to 100,000 windows)."""
    one = [gather_windows(x, ends[i : i + 1], WINDOW) for i in range(220)]
    if isinstance(model, RidgeWindows):
        call = model
    else:
        import torch

        model.eval()

        def call(w):
            with torch.inference_mode():
                return model(torch.from_numpy(w))
    times = []
    for w in one:
        t = time.perf_counter()
        call(w)
        times.append(time.perf_counter() - t)
    batch_1_ms = 1e3 * float(np.min(times[20:]))
    many = ends[: 100_000]
    t = time.perf_counter()
    _predict(model, x, many)
    return batch_1_ms, many.size / (time.perf_counter() - t)


def _row(name, model, train_s, test, norm) -> str:
    x, ends = _stack(test, norm)
    truth = np.concatenate([s.targets for s in test])[ends]
    err = target_errors(decode_targets(_predict(model, x, ends), COLUMNS, norm), truth, COLUMNS)
    b1, batched = _speed(model, x, ends)
    return (f"| {name} | {err['r_mm']['rmse']:.2f} | {err['h_mm']['rmse']:.2f} | "
            f"{err['azimuth_deg']['mae_deg']:.2f} | {train_s:.0f} | {b1:.3f} | {batched:,.0f} |")


def compare(args) -> int:
    """GRU, convolution and ridge trained on seed 0's tables, scored on seed 1's."""
    from camwhisker.learn.train import TrainOptions, train

    tables = whisker_tables(args.rows, seed=0)
    test = whisker_tables(max(args.rows // 4, 2 * WINDOW), seed=1)
    training, validation = split_by_table(tables, WINDOW)
    rows = ["| model | r RMSE (mm) | h RMSE (mm) | azimuth MAE (deg) | train (s) | "
            "batch 1 (ms/sample) | batched (samples/s) |", "|---|---|---|---|---|---|---|"]
    norm = None
    import torch

    for kind in ("gru", "conv"):
        torch.manual_seed(0)
        net = (window_gru(len(COLUMNS.inputs), COLUMNS.n_encoded) if kind == "gru" else None)
        opts = TrainOptions(kind="conv", epochs=args.epochs)
        trained = train(training, validation, COLUMNS, WINDOW, opts, progress=False, net=net)
        norm = trained.norm
        rows.append(_row(f"{kind} 32 (best epoch {trained.summary['best_epoch']})",
                         trained.net, trained.summary["train_s"], test, norm))  # fmt: skip
        print(rows[-1], flush=True)
    t = time.perf_counter()
    x, ends = _stack(training, norm)
    y = np.concatenate([encode_targets(s.targets, COLUMNS, norm) for s in training])
    ridge = RidgeWindows(len(COLUMNS.inputs)).fit(x, y, ends)
    rows.append(_row("ridge, 1024 random features", ridge, time.perf_counter() - t, test, norm))
    print("\n".join(rows))
    n_test = sum(s.inputs.shape[0] for s in test)
    print(f"training: {args.rows:,} rows of seed 0 ({len(tables)} tables, the last "
          f"{len(validation)} for validation); test: seed 1, {n_test:,} rows")
    return 0


def scale(args) -> int:
    """learn --kind conv's defaults on ``args.rows`` rows (seed 0); speed on seed 1's windows."""
    from camwhisker.learn.train import TrainOptions, train

    t = time.perf_counter()
    tables = whisker_tables(args.rows, seed=0)
    training, validation = split_by_table(tables, WINDOW)
    opts = TrainOptions(kind="conv")
    trained = train(training, validation, COLUMNS, WINDOW, opts, progress=True)
    s = trained.summary
    print(f"{args.rows:,} rows x {len(COLUMNS.inputs)} channels, window {WINDOW}, "
          f"{opts.arch}: {s['epochs_run']} epochs of {opts.samples_per_epoch:,} windows, "
          f"best {s['best_epoch']}, training {s['train_s']:.0f} s "
          f"(with data generation {time.perf_counter() - t:.0f} s)")
    test = whisker_tables(ROWS_PER_TABLE, seed=1)
    print(_row("scale", trained.net, s["train_s"], test, trained.norm))
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="camwhisker dev learn-bench", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="what", required=True)
    c = sub.add_parser("compare", help="GRU, convolution and ridge on one task")
    c.add_argument("--rows", type=int, default=300_000, help="training rows")
    c.add_argument("--epochs", type=int, default=15)
    s = sub.add_parser("scale", help="learn --kind conv on 1.5 M rows: time and speed")
    s.add_argument("--rows", type=int, default=1_500_000)
    o = sub.add_parser("sensor", help="on our sensor's simulated runs, beside GM, MF, fused")
    o.add_argument("--seed", type=int, default=0,
                   help="calibration and training runs' seed (scored on seed + 1)")
    o.add_argument("--window", type=int, default=SensorOptions.window, help="frames per window")
    o.add_argument("--epochs", type=int, default=SensorOptions.epochs)
    o.add_argument("--inputs", action="append", metavar="A,B,...",
                   help="an input set to train and compare (repeat for several); some of "
                        f"{', '.join(SENSOR_INPUTS)}; default: "
                        + "; ".join(",".join(v) for v in SensorOptions.variants))
    o.add_argument("--kind", choices=KINDS, default=SensorOptions.kind, help="model kind")
    o.add_argument("--out", metavar="DIR", help="save each model as DIR/<level>/<variant>")
    r = sub.add_parser("real", help="on a real whisker's recordings, the authors' metric")
    r.add_argument("--data", required=True, metavar="PATH.npz",
                   help="the recordings (camwhisker.bench.learn_real: keys and metric)")
    r.add_argument("--kind", action="append", choices=KINDS,
                   help=f"learn's model kind (repeat for several; default {KINDS[0]})")
    args = p.parse_args(argv)
    return {"compare": compare, "scale": scale, "sensor": sensor, "real": real}[args.what](args)


def real(args) -> int:
    """learn and the kNN reference on the time split of a real whisker's recordings."""
    from camwhisker.bench.learn_real import format_real, run_real
    from camwhisker.learn.series import LearnError

    try:
        result = run_real(args.data, tuple(args.kind or KINDS[:1]), progress=True)
    except LearnError as exc:
        print(f"camwhisker dev learn-bench real: {exc}", file=sys.stderr)
        return 2
    print(format_real(result))
    return 0


def sensor(args) -> int:
    """The learned estimator on our sensor: the Markdown table of learn_sensor."""
    from camwhisker.learn.series import LearnError

    variants = tuple(tuple(c.strip() for c in v.split(",") if c.strip())
                     for v in args.inputs or ()) or SensorOptions.variants
    opts = SensorOptions(window=args.window, epochs=args.epochs, variants=variants,
                         kind=args.kind)  # fmt: skip
    try:
        for v in variants:
            sensor_columns(v)
        result = run_sensor(args.seed, opts, args.out)
    except LearnError as exc:
        print(f"camwhisker dev learn-bench sensor: {exc}", file=sys.stderr)
        return 2
    print(format_sensor(result, args.seed, opts))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
