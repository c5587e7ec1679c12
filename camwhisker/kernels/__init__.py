"""The per-pixel loops, compiled: ahead of time at install, numba's JIT where that build is missing.

Each kernel is a numba function (:func:`kernel`) beside its kin in
``camwhisker/kernels/*.py`` (numpy and numba only, so that the install can
import them), called by the Python function that states its contract in
:mod:`camwhisker.vision` (or :mod:`camwhisker.sensor.polygon`). The install
(``setup.py``, :mod:`camwhisker.kernels.build`) compiles the same source with
numba's AOT compiler into ``camwhisker/kernels/_aot``, one entry per signature
the kernel lists, for this machine's CPU, with a digest of :data:`MODULES`'
source and the CPU: a first run then compiles nothing. A call whose arguments
match none of the listed signatures, and every call where ``_aot`` is missing or
its digest differs (one warning), goes to numba's JIT (``cache=True``), as before.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import logging

import llvmlite.binding as llvm
import numpy as np
from numba import njit, types
from numba.core import sigutils
from numba.extending import typeof_impl
from numba.np.numpy_support import as_dtype

__all__ = ["MODULES", "Kernel", "compiled_module", "kernel", "registered", "source_digest"]

log = logging.getLogger(__name__)

# The modules whose kernels the install compiles; their source makes the digest.
MODULES = (
    "camwhisker.kernels.polygon",
    "camwhisker.kernels.blobs",
    "camwhisker.kernels.colour",
    "camwhisker.kernels.lk",
    "camwhisker.kernels.pose",
    "camwhisker.kernels.tip",
    "camwhisker.kernels.tracker",
)
AOT_MODULE = "camwhisker.kernels._aot"

_registry: dict[str, Kernel] = {}
_aot_state: list = []  # [module or None], filled on the first call of any kernel


class Kernel:
    """A numba kernel: the install's compiled entry whose signature the arguments
    match, else numba's JIT (``.jit``, a dispatcher; ``.py_func``, the Python source).

    Inside another kernel it is typed as its dispatcher, so kernels call kernels.
    """

    def __init__(self, py_func, signatures: tuple[str, ...]):
        self.py_func = py_func
        self.jit = njit(cache=True, nogil=True, error_model="numpy")(py_func)
        self.signatures = signatures
        self.name = f"{py_func.__module__.rsplit('.', 1)[-1]}__{py_func.__name__}"
        self.__doc__, self.__name__ = py_func.__doc__, py_func.__name__
        self._call = self._first_call

    def entry_names(self) -> list[str]:
        """The names of this kernel's compiled entries in ``_aot``, one per signature."""
        return [f"{self.name}__{i}" for i in range(len(self.signatures))]

    def __call__(self, *args):
        return self._call(*args)

    def _first_call(self, *args):
        aot = compiled_module()
        entries = [] if aot is None else [getattr(aot, n) for n in self.entry_names()]
        self._call = _dispatcher(self.py_func, self.signatures, entries, self.jit)
        return self._call(*args)


@typeof_impl.register(Kernel)
def _typeof_kernel(val, c):
    return types.Dispatcher(val.jit)


def kernel(*signatures: str):
    """Decorator: a :class:`Kernel`, compiled at install for each signature, its
    arguments' types in numba's notation (e.g. ``"f8[:, ::1], i8"``; the return
    type is inferred); none for one that only other kernels call."""

    def wrap(py_func) -> Kernel:
        k = Kernel(py_func, signatures)
        _registry[k.name] = k
        return k

    return wrap


def registered() -> list[Kernel]:
    """Every kernel of :data:`MODULES`, imported."""
    for name in MODULES:
        importlib.import_module(name)
    return [k for k in _registry.values() if k.py_func.__module__ in MODULES]


def source_digest() -> int:
    """A 63-bit digest of :data:`MODULES`' source and this machine's CPU (the build's
    code is for the CPU it ran on, as the JIT's): the compiled module's must equal it."""
    h = hashlib.sha256(
        f"{llvm.get_host_cpu_name()} {llvm.get_host_cpu_features().flatten()}".encode()
    )
    for name in MODULES:
        with open(importlib.util.find_spec(name).origin, "rb") as f:
            h.update(f.read())
    return int.from_bytes(h.digest()[:8], "little") >> 1


def compiled_module():
    """The install's compiled kernels, or None (with one warning) where they are
    missing, or were built from other source or on another CPU."""
    if not _aot_state:
        try:
            aot = importlib.import_module(AOT_MODULE)
            why = (
                "built from other source or for another CPU"
                if aot.source_digest() != source_digest()
                else ""
            )
        except ImportError:
            aot, why = None, "not built"
        if why:
            log.warning(
                "camwhisker's compiled kernels are %s (reinstall: pip install -e .); "
                "numba compiles them on first use instead (~30 s, cached)",
                why,
            )
            aot = None
        _aot_state.append(aot)
    return _aot_state[0]


def _dispatcher(py_func, signatures, entries, jit):
    """A function of ``py_func``'s arguments that calls the first compiled entry whose
    signature the arguments have exactly, else ``jit``.

    A compiled entry trusts its arguments' types (an array of another dtype or
    layout is read as if it had its own: garbage), so each is checked first: as
    one generated expression, since a generic loop over the arguments costs more
    than many kernels' calls (~2 us).
    """
    if not entries:
        return jit
    n = py_func.__code__.co_argcount
    params = ", ".join(f"a{i}" for i in range(n))
    env = {"jit": jit, "ndarray": np.ndarray, "bools": (bool, np.bool_),
           "ints": (int, np.integer), "reals": (float, int, np.floating, np.integer)}  # fmt: skip
    lines = [f"def call({params}):"]
    for k, (signature, entry) in enumerate(zip(signatures, entries, strict=True)):
        args, _ = sigutils.normalize_signature(signature)
        if len(args) != n:
            raise TypeError(
                f"{py_func.__name__}: signature {signature!r} has {len(args)} of {n} arguments"
            )
        checks = []
        for i, t in enumerate(args):
            checks.append(_check(f"a{i}", t, f"d{k}_{i}", env))
        env[f"f{k}"] = entry
        lines.append(f"    if {' and '.join(checks)}:\n        return f{k}({params})")
    lines.append(f"    return jit({params})")
    exec("\n".join(lines), env)
    return env["call"]


def _check(name: str, t, dtype_name: str, env: dict) -> str:
    """A Python expression: whether the value ``name`` has numba type ``t`` exactly."""
    if isinstance(t, types.Array):
        env[dtype_name] = as_dtype(t.dtype)
        c = f" and {name}.flags.c_contiguous" if t.layout == "C" else ""
        return (f"type({name}) is ndarray and {name}.dtype == {dtype_name}"
                f" and {name}.ndim == {t.ndim}{c}")  # fmt: skip
    if isinstance(t, types.Boolean):
        return f"isinstance({name}, bools)"
    if isinstance(t, types.Integer):
        return f"isinstance({name}, ints) and not isinstance({name}, bools)"
    if isinstance(t, types.Float):
        return f"isinstance({name}, reals)"
    raise TypeError(f"kernel signature: no argument check for numba type {t}")
