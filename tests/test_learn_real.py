"""The real-whisker benchmark (camwhisker.bench.learn_real) on a small made-up file of the same
layout: the authors' metric by hand, the time split, and a file without a key named."""

from __future__ import annotations

import numpy as np
import pytest

from camwhisker.bench import learn_real
from camwhisker.bench.learn import main as bench_main
from camwhisker.learn.series import LearnError

#: Recordings and rows: each a slow sweep of R 0 -> 100 -> 0 at one (H, O).
CONFIGS = [(5.0, 0.0), (10.0, 90.0), (15.0, 180.0), (10.0, 270.0)]
ROWS = 600


def _fake(path, seed=0):
    rng = np.random.default_rng(seed)
    sig, r, h, o = [], [], [], []
    for hh, oo in CONFIGS:
        rr = 50.0 - 50.0 * np.cos(np.linspace(0.0, 6 * np.pi, ROWS))
        a = np.radians(oo)
        s = np.stack([rr * np.cos(a), rr * np.sin(a), rr * hh / 10.0], axis=1)
        sig.append(s + 0.5 * rng.standard_normal(s.shape))
        r.append(rr), h.append(np.full(ROWS, hh)), o.append(np.full(ROWS, oo))
    np.savez(path, signals=np.concatenate(sig).astype(np.float32), R=np.concatenate(r),
             H=np.concatenate(h), O=np.concatenate(o),
             offsets=np.arange(len(CONFIGS) + 1) * ROWS)  # fmt: skip
    return path


def test_authors_metric_by_hand():
    truth = np.array([[0.0, 5.0, 0.0], [100.0, 15.0, 90.0], [50.0, 10.0, 180.0]])
    assert learn_real.authors_metric(truth, truth)["mean_mm"] == 0.0
    # R 10 mm out (range 100): 10 mm in (x, y) along the azimuth, on every row
    m = learn_real.authors_metric(truth + [10.0, 0.0, 0.0], truth)
    assert m["mean_mm"] == pytest.approx(10.0) and m["r_mm"] == pytest.approx(10.0)
    # H 1 cm out over a 10 cm range: 10 mm in z; azimuth 360 deg out is no error
    m = learn_real.authors_metric(truth + [0.0, 1.0, 360.0], truth)
    assert m["mean_mm"] == pytest.approx(10.0) and m["h_mm"] == pytest.approx(10.0)
    assert m["azimuth_deg"] == pytest.approx(0.0, abs=1e-9)
    # azimuth 90 deg out at Rn 100: sqrt(2) * 100 mm on that row; Rn 0: none
    m = learn_real.authors_metric(truth + [0.0, 0.0, 90.0], truth)
    assert m["mean_mm"] == pytest.approx((100.0 * np.sqrt(2) + 50.0 * np.sqrt(2)) / 3)


def test_run_real_scores_learn_and_the_reference_on_the_time_split(tmp_path):
    result = learn_real.run_real(_fake(tmp_path / "w.npz"), kinds=("knn",))
    n_learn, n_score, n_rec = result["_windows"]
    assert n_rec == len(CONFIGS) and n_learn == len(CONFIGS) * (480 - learn_real.WINDOW + 1)
    assert n_score == len(CONFIGS) * (120 - learn_real.WINDOW + 1)
    (name, ours), (_, ref) = [(k, v) for k, v in result.items() if not k.startswith("_")]
    assert name.startswith("learn --kind knn (k ")
    # the configurations are told apart by the channels' ratios and R by their size: both
    # score ~0.3 mm (seeds 0-2); 2 mm allows for platforms, far from one configuration
    # taken for another (tens of mm)
    assert ours["mean_mm"] < 2.0 and ref["mean_mm"] < 2.0
    assert 0.0 < ours["batch1_ms"] < 1e3
    text = learn_real.format_real(result)
    assert f"| {learn_real.PAPER_MM:.2f} |" in text and "learn --kind knn" in text


def test_a_missing_key_is_named(tmp_path, capsys):
    path = tmp_path / "bad.npz"
    np.savez(path, signals=np.zeros((10, 3)), R=np.zeros(10))
    with pytest.raises(LearnError, match=r"bad.npz: missing key\(s\) H, O, offsets"):
        learn_real.load_recordings(path)
    assert bench_main(["real", "--data", str(path)]) == 2
    assert "bad.npz: missing key(s)" in capsys.readouterr().err
