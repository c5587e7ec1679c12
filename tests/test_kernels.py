"""The install's compiled kernels (camwhisker.kernels): in use, and equal to their source."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from numba import types
from numba.core import sigutils
from numba.np.numpy_support import as_dtype

from camwhisker.kernels import _dispatcher, compiled_module, parse_signature, registered
from camwhisker.kernels.polygon import polygon_area, polygon_centroid, polygon_centroid_jacobian

ROOT = Path(__file__).resolve().parents[1]

# The front end on the sample's first frames in a fresh process: which kernels numba's JIT
# compiled (none, where the install's compiled entries cover every call).
FRONT_END = """
import itertools, json, sys
from camwhisker.io.sources import open_source
from camwhisker.kernels import compiled_module, registered
from camwhisker.sensor.file import load_sensor
from camwhisker.vision.stream import track
root = sys.argv[1]
video = open_source(f"{root}/sample_frames/nominal_mjpg.avi")
frames = (f.image for f in itertools.islice(video, 4))
rows = list(track(frames, load_sensor(f"{root}/sample_frames/nominal_mjpg.sensor.toml")))
heavy = [m for m in ("numba", "scipy") if m in sys.modules]  # before .jit, which imports numba
print(json.dumps({"compiled": compiled_module() is not None, "frames": len(rows), "heavy": heavy,
                  "jit": [k.name for k in registered() if k.jit.signatures]}))
"""


def test_the_front_end_compiles_nothing_after_install():
    out = subprocess.run([sys.executable, "-c", FRONT_END, str(ROOT)], capture_output=True,
                         text=True, timeout=120, check=True)  # fmt: skip
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["compiled"], "the install did not build camwhisker/kernels/_aot"
    assert got["frames"] == 4
    # Neither is needed: the compiled entries run without numba, the blur's fits and FFT
    # are numpy's. Each costs ~0.1 s of every batch's start-up.
    assert got["heavy"] == []
    assert got["jit"] == []  # a kernel listed here was compiled (or loaded from numba's cache)


def test_every_kernel_has_its_compiled_entries():
    aot = compiled_module()
    names = [n for k in registered() for n in k.entry_names()]
    assert len(names) >= 20  # every signature the front end calls (tests above)
    assert [n for n in names if not hasattr(aot, n)] == []


def test_signatures_read_as_numba_reads_them():
    # The argument checks read the signatures without numba: the same dtype, ndim and
    # layout as numba's own parse, for every signature the install compiles.
    n = 0
    for k in registered():
        for signature in k.signatures:
            ours = parse_signature(signature)
            theirs, _ = sigutils.normalize_signature(signature)
            assert len(ours) == len(theirs), signature
            for (kind, dtype, ndim, layout), t in zip(ours, theirs, strict=True):
                assert dtype == as_dtype(t.dtype if isinstance(t, types.Array) else t), signature
                if isinstance(t, types.Array):
                    assert (kind, ndim, layout) == ("array", t.ndim, t.layout), signature
                else:
                    assert ndim == 0, signature
                n += 1
    assert n >= 60  # every argument of the >= 20 entries


def test_a_call_of_another_type_is_not_given_to_a_compiled_entry():
    # A compiled entry trusts its arguments' types: a float32 or strided array would be
    # read as contiguous float64, garbage; the checks send such a call to numba's JIT.
    def f(uv, n):
        return uv, n

    call = _dispatcher(f, ("f8[:, ::1], i8",), [lambda *a: "compiled"], lambda *a: "jit")
    uv = np.zeros((4, 2))
    assert call(uv, 3) == "compiled"
    assert call(uv, np.int32(3)) == "compiled"
    assert call(uv.astype(np.float32), 3) == "jit"
    assert call(np.zeros((4, 4))[:, ::2], 3) == "jit"
    assert call(np.zeros(8), 3) == "jit"
    assert call(uv.tolist(), 3) == "jit"
    assert call(uv, 3.0) == "jit"
    assert call(uv, True) == "jit"


def test_compiled_polygon_kernels_equal_their_python_source():
    rng = np.random.default_rng(7)
    t = np.sort(rng.uniform(0, 2 * np.pi, 40))
    uv = np.column_stack([300 + 40 * np.cos(t), 200 + 25 * np.sin(t)]) + rng.normal(0, 0.3, (40, 2))
    duv = rng.standard_normal((40, 2, 3))
    # The same float64 sums in the same order: equal to rounding (1e-12 relative).
    np.testing.assert_allclose(polygon_centroid(uv), polygon_centroid.py_func(uv), rtol=1e-12)
    assert abs(polygon_area(uv) / polygon_area.py_func(uv) - 1) < 1e-12
    jac = polygon_centroid_jacobian.py_func(uv, duv)
    np.testing.assert_allclose(polygon_centroid_jacobian(uv, duv), jac, rtol=1e-12, atol=1e-12)
    # numpy's error model, as the JIT's: a degenerate polygon's centroid is nan, no exception.
    assert np.isnan(polygon_centroid(np.ones((4, 2)))).all()
