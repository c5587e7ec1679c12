"""Strict JSON (issue #21 item 8): every file the package writes parses without NaN."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from camwhisker.files.jsonfile import dumps, plain


def _no_constants(name):
    raise ValueError(f"bare {name} in JSON")


def strict_loads(text: str):
    """``json.loads`` that refuses NaN and Infinity, as strict readers do."""
    return json.loads(text, parse_constant=_no_constants)


def test_non_finite_numbers_become_null_and_numpy_plain():
    value = {"nan": math.nan, "inf": np.float64(-np.inf), "arr": np.array([1.5, np.nan]),
             "n": np.int64(3), "flag": np.bool_(True), "path": Path("a/b.csv"),
             "nested": [{"x": (math.nan, 2.0)}]}
    text = dumps(value, sort_keys=True)
    assert text == ('{"arr": [1.5, null], "flag": true, "inf": null, "n": 3, "nan": null, '
                    '"nested": [{"x": [null, 2.0]}], "path": "a/b.csv"}')
    assert strict_loads(text)["n"] == 3
    assert plain(np.float32(0.25)) == 0.25  # exact in binary: no tolerance needed


def test_plain_json_refuses_what_strict_json_refuses():
    # What the package wrote before: json.dumps lets NaN through unless told not to.
    with pytest.raises(ValueError, match="bare NaN"):
        strict_loads(json.dumps({"max_dist_mm": math.nan}))


def test_sidecars_are_strict(tmp_path):
    from camwhisker.io.signals import write_sidecar

    path = write_sidecar(tmp_path / "t.csv", {"phi_rmse_deg": np.float64(np.nan), "rows": 0})
    assert strict_loads(path.read_text()) == {"phi_rmse_deg": None, "rows": 0}
