"""camwhisker learn / predict: a known relation recovered through the model directory by
the conv kind, angles across +-180 deg, and every bad input named (the knn kind:
test_learn_knn.py).

The tables: inputs a, b (the cosine and sine of a slowly turning angle, through +-180 deg
every few hundred rows) and c (noise); targets y = 2 c[t] - c[t - 3] (needs the window's
history) and z, the angle (deg). Noise-free, so the error left is the small net's fit
after a few epochs.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from camwhisker.cli import main
from camwhisker.files.tables import read_columns, write_csv

WINDOW = 8
ROWS = 2000
#: y's RMSE after 8 epochs is ~0.1 of y's std (std ~2.2); 0.2 allows for platforms and
#: seeds, while a model without the lag (c[t] alone) is off by ~0.45.
Y_RMSE_SHARE_MAX = 0.2
#: Mean absolute angle error (deg) within 10 deg of +-180 and overall (~1.8 deg both); a
#: model that regressed raw degrees would be off by ~90 deg near +-180.
Z_MAE_MAX_DEG = 4.0


def _table(path, seed, rows=ROWS, smooth=False):
    """``smooth``: c a sum of three sines and y = c[t] + 5 (c[t] - c[t - 4]) instead (a
    relation of the window's level and slope: test_learn_knn.py)."""
    rng = np.random.default_rng(seed)
    angle = np.cumsum(rng.uniform(0.5, 2.5, rows)) + rng.uniform(0, 360)
    z = (angle + 180.0) % 360.0 - 180.0
    if smooth:
        t = np.arange(rows)
        c = sum(np.sin(2 * np.pi * t / p + rng.uniform(0, 2 * np.pi)) for p in (37, 91, 210))
        y = c + 5.0 * (c - np.concatenate([np.zeros(4), c[:-4]]))
    else:
        c = rng.standard_normal(rows)
        y = 2.0 * c - np.concatenate([np.zeros(3), c[:-3]])
    a, b = np.cos(np.radians(angle)), np.sin(np.radians(angle))
    write_csv(path, {"t_s": np.arange(rows) / 100.0, "a": a, "b": b, "c": c, "y": y, "z": z})
    return path


def _learn_args(tables, out, *extra):
    args = ["learn", "--inputs", "a,b,c", "--targets", "y", "--angle-targets", "z",
            "--window", str(WINDOW), "--out", str(out), "--epochs", "8",
            "--kind", "conv"]  # fmt: skip
    for t in tables:
        args += ["--table", str(t)]
    return args + list(extra)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    d = tmp_path_factory.mktemp("learn")
    tables = [_table(d / f"t{k}.csv", k) for k in range(3)]
    assert main(_learn_args(tables, d / "model")) == 0
    return d


def test_round_trip_recovers_the_relation_and_the_angle_across_180(trained, tmp_path):
    table = _table(tmp_path / "new.csv", 99)  # a seed no model saw
    out = tmp_path / "p.csv"
    assert main(["predict", "--model", str(trained / "model"), "--table", str(table),
                 "--out", str(out)]) == 0  # fmt: skip
    check_predictions(out, table, WINDOW, Y_RMSE_SHARE_MAX, Z_MAE_MAX_DEG)


def check_predictions(out, table, window, y_share_max, z_mae_max_deg):
    """The predictions ``out`` of ``table`` (:func:`_table`): y's RMSE under ``y_share_max``
    of its std, z's mean absolute error under ``z_mae_max_deg`` overall and near +-180."""
    pred, truth = read_columns(out), read_columns(table)
    assert list(pred) == ["y", "z"] and pred["y"].size == truth["y"].size
    assert np.isnan(pred["y"][: window - 1]).all() and np.isfinite(pred["y"][window - 1 :]).all()
    rows = slice(window - 1, None)
    rmse = np.sqrt(np.mean((pred["y"][rows] - truth["y"][rows]) ** 2))
    assert rmse < y_share_max * truth["y"].std()
    err = (pred["z"][rows] - truth["z"][rows] + 180.0) % 360.0 - 180.0
    near = np.abs(truth["z"][rows]) > 170.0
    assert near.sum() > 20  # the table does cross +-180 deg
    assert np.abs(err[near]).mean() < z_mae_max_deg and np.abs(err).mean() < z_mae_max_deg
    assert (np.abs(pred["z"][rows]) <= 180.0).all()


def test_model_directory_records_the_training(trained):
    config = json.loads((trained / "model" / "config.json").read_text())
    assert config["inputs"] == ["a", "b", "c"] and config["angle_targets"] == ["z"]
    assert config["window"] == WINDOW and config["format"] == 1
    # three tables of 2000 rows: each one's last 20 % held out to choose the epoch, then
    # the final model fitted on every row
    training = config["training"]
    assert training["training_rows"] == 3 * (ROWS * 4 // 5)
    assert len(training["validation_tables"]) == 3 and training["validation"] == "time"
    assert training["final_training_rows"] == 3 * ROWS
    assert config["architecture"]["kind"] == "conv"
    assert len(training["history"]) == training["epochs_run"] >= training["best_epoch"] >= 1
    assert len(config["normalisation"]["input_mean"]) == 3
    assert len(config["weights"]["weights.npz"]) == 64


def _predict_error(model, table, out, capsys):
    code = main(["predict", "--model", str(model), "--table", str(table), "--out", str(out)])
    return code, capsys.readouterr().err


def test_bad_model_directory_is_named(trained, tmp_path, capsys):
    import shutil

    table = _table(tmp_path / "t.csv", 5, rows=50)
    out = tmp_path / "p.csv"
    model = tmp_path / "m"
    shutil.copytree(trained / "model", model)
    weights = model / "weights.npz"
    data = bytearray(weights.read_bytes())
    data[-40] ^= 1
    weights.write_bytes(bytes(data))
    code, err = _predict_error(model, table, out, capsys)
    assert code == 2 and f"{weights}: altered since training" in err
    weights.unlink()
    code, err = _predict_error(model, table, out, capsys)
    assert code == 2 and f"{weights}: missing" in err
    shutil.copy(trained / "model" / "weights.npz", weights)
    config = json.loads((model / "config.json").read_text())
    config["format"] = 2
    (model / "config.json").write_text(json.dumps(config))
    code, err = _predict_error(model, table, out, capsys)
    assert code == 2 and "config.json: model format 2" in err and "train it again" in err
    (model / "config.json").unlink()
    code, err = _predict_error(model, table, out, capsys)
    assert code == 2 and f"{model / 'config.json'}: missing" in err
    assert not out.exists()


def test_bad_tables_are_named(trained, tmp_path, capsys):
    good = _table(tmp_path / "good.csv", 7, rows=40)
    cols = read_columns(good)
    missing = tmp_path / "missing.csv"
    write_csv(missing, {k: v for k, v in cols.items() if k != "b"})
    nonfinite = tmp_path / "nan.csv"
    write_csv(nonfinite, {**cols, "c": np.where(np.arange(40) == 9, np.nan, cols["c"])})
    short = _table(tmp_path / "short.csv", 8, rows=WINDOW - 1)
    cases = [(missing, "missing column b"), (nonfinite, "row 11, column c: not a finite"),
             (short, f"7 rows, fewer than the window of {WINDOW}")]  # fmt: skip
    for table, says in cases:
        out = tmp_path / "m"
        assert main(_learn_args([good, table], out)) == 2
        assert f"{table}: " in (err := capsys.readouterr().err) and says in err, err
        assert not out.exists()
        code, err = _predict_error(trained / "model", table, tmp_path / "p.csv", capsys)
        assert code == 2 and f"{table}: " in err and says in err, err
        assert not (tmp_path / "p.csv").exists()


def test_core_imports_without_torch_and_learn_names_the_extra(tmp_path):
    table = _table(tmp_path / "t.csv", 3, rows=40)
    code = (
        "import sys; sys.modules['torch'] = None\n"  # makes `import torch` fail
        "import camwhisker.cli, camwhisker.learn.series, camwhisker.learn.predict\n"
        "sys.exit(camwhisker.cli.main(['learn', '--table', sys.argv[1], '--table', sys.argv[1],"
        " '--inputs', 'a,b', '--targets', 'y', '--window', '8', '--out', sys.argv[2],"
        " '--kind', 'conv']))\n"
    )
    r = subprocess.run([sys.executable, "-c", code, str(table), str(tmp_path / "m")],
                       capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 2, r.stderr
    assert "need torch, which is not installed" in r.stderr and "camwhisker[learn]" in r.stderr
    assert not (tmp_path / "m").exists()


def test_convolution_computes_the_last_row_as_the_full_causal_stack():
    # the forward pass computes only the rows that reach the last one; the full causal
    # stack (every row, zero-padded on the left) must give the same output
    import torch

    from camwhisker.learn.net import build_net, conv_dilations

    dilations = conv_dilations(40)
    assert dilations == [1, 2, 4, 8, 16]  # 1 + 2 * 31 = 63 rows seen >= 40
    torch.manual_seed(0)
    net = build_net({"kind": "conv", "hidden": 8, "dilations": dilations}, 3, 4)
    x = torch.randn(5, 40, 3)
    h = x.transpose(1, 2)
    for conv in net.convs:
        h = torch.relu(conv(torch.nn.functional.pad(h, (2 * conv.dilation[0], 0))))
    full = net.head(h[:, :, -1])
    with torch.no_grad():
        # float32 sums in another order: 1e-5 is ~100 ulps of outputs of order 0.1-1
        assert torch.allclose(net(x), full, atol=1e-5)
