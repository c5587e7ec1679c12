"""camwhisker learn's default kind, knn: a relation of the window's level and slope recovered
through the model directory without torch, the time split, and features computed in chunks.

The tables: inputs a, b (the cosine and sine of a slowly turning angle, through +-180 deg)
and c (a smooth random signal); targets y = c[t] + 5 (c[t] - c[t - 4]) (needs the window's
slope)
and z, the angle (deg).
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from camwhisker.cli import main
from camwhisker.learn import knn as knn_module
from camwhisker.learn.knn import K_CHOICES, window_features
from camwhisker.learn.series import LearnError, Series, split_in_time
from tests.test_learn import _table as learn_table
from tests.test_learn import check_predictions

WINDOW = 8
ROWS = 2000
#: y's RMSE is ~0.23 of y's std with 6000 training rows (seeds 0-5); 0.35 allows for
#: seeds, while the best line in c[t] alone (no slope) is off by ~0.82 of it.
Y_RMSE_SHARE_MAX = 0.35
#: Mean absolute angle error (deg), overall and within 10 deg of +-180 (~2.5 deg); averaging
#: raw degrees of neighbours on both sides of +-180 would be off by ~180 there.
Z_MAE_MAX_DEG = 5.0


def _table(path, seed, rows=ROWS):
    return learn_table(path, seed, rows, smooth=True)


# learn and predict with torch made unimportable: the knn kind needs none
NO_TORCH = ("import sys; sys.modules['torch'] = None\n"
            "import camwhisker.cli\n"
            "sys.exit(camwhisker.cli.main(sys.argv[1:]))\n")  # fmt: skip


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    d = tmp_path_factory.mktemp("knn")
    args = ["learn", "--inputs", "a,b,c", "--targets", "y", "--angle-targets", "z",
            "--window", str(WINDOW), "--out", str(d / "model")]  # fmt: skip
    for k in range(3):
        args += ["--table", str(_table(d / f"t{k}.csv", k))]
    r = subprocess.run([sys.executable, "-c", NO_TORCH, *args], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return d


def test_round_trip_without_torch_recovers_the_relation_and_the_angle(trained, tmp_path):
    table = _table(tmp_path / "new.csv", 99)  # a seed no model saw
    out = tmp_path / "p.csv"
    r = subprocess.run([sys.executable, "-c", NO_TORCH, "predict", "--model",
                        str(trained / "model"), "--table", str(table), "--out", str(out)],
                       capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    check_predictions(out, table, WINDOW, Y_RMSE_SHARE_MAX, Z_MAE_MAX_DEG)


def test_model_directory_holds_every_row_and_the_chosen_k(trained):
    model = trained / "model"
    config = json.loads((model / "config.json").read_text())
    assert config["architecture"]["kind"] == "knn"
    assert config["architecture"]["k"] in K_CHOICES
    training = config["training"]
    # each table's first 80 % to choose k on its last 20 %, then every row in the model
    assert training["training_rows"] == 3 * (ROWS * 4 // 5)
    assert len(training["validation_tables"]) == 3 and training["validation"] == "time"
    assert training["final_training_rows"] == 3 * ROWS
    assert set(training["validation_score_per_k"]) == {str(k) for k in K_CHOICES}
    with np.load(model / "weights.npz", allow_pickle=False) as npz:
        assert npz["rows"].shape == (3 * ROWS, 3) and npz["targets"].shape == (3 * ROWS, 2)
        assert npz["lengths"].tolist() == [ROWS] * 3


def test_split_in_time_keeps_every_table_and_a_short_one_whole():
    def series(name, n):
        return Series(name, np.zeros((n, 1)), np.arange(n, dtype=float)[:, None])

    training, validation = split_in_time([series("long", 100), series("short", 12)], 8)
    assert [s.path for s in training] == ["long", "short"]
    assert training[0].inputs.shape[0] == 80 and training[1].inputs.shape[0] == 12
    assert [s.path for s in validation] == ["long"] and validation[0].targets[0, 0] == 80
    with pytest.raises(LearnError, match="no table holds 16 rows or more.*short"):
        split_in_time([series("short", 12)], 8)


def test_features_do_not_depend_on_the_chunk(monkeypatch):
    rng = np.random.default_rng(0)
    x = rng.standard_normal((50, 2))
    ends = np.arange(WINDOW - 1, 50)
    whole = window_features(x, ends, WINDOW)
    monkeypatch.setattr(knn_module, "CHUNK", 7)
    # the same numbers, computed in another grouping: equal to float64 rounding
    np.testing.assert_allclose(window_features(x, ends, WINDOW), whole, rtol=0, atol=1e-12)
    # by hand for one window: last, mean, slope, min, max of column 0; the roughness
    w = x[ends[3] - WINDOW + 1 : ends[3] + 1]
    slope = np.polyfit(np.arange(WINDOW), w[:, 0], 1)[0]
    expect = [w[-1, 0], w[:, 0].mean(), slope, w[:, 0].min(), w[:, 0].max()]
    np.testing.assert_allclose(whole[3, 0::2][:5], expect, atol=1e-12)
    assert whole[3, -1] == pytest.approx(np.abs(np.diff(w, axis=0)).mean(), abs=1e-12)


def test_fewer_training_windows_than_k_uses_them_all(tmp_path):
    # one table of 40 rows, window 8: its first 32 rows hold 25 training windows, under 40
    table = str(_table(tmp_path / "s.csv", 5, rows=40))
    assert main(["learn", "--inputs", "a,b,c", "--targets", "y", "--angle-targets", "z",
                 "--window", str(WINDOW), "--table", table, "--out",
                 str(tmp_path / "m")]) == 0  # fmt: skip
    config = json.loads((tmp_path / "m" / "config.json").read_text())
    assert set(config["training"]["validation_score_per_k"]) == {"5", "10", "20", "25"}
    assert config["architecture"]["k"] in (5, 10, 20, 25)
    assert main(["predict", "--model", str(tmp_path / "m"), "--table", table,
                 "--out", str(tmp_path / "p.csv")]) == 0  # fmt: skip
