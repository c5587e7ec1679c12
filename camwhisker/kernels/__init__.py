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
numba itself is imported only then (or by the build): with the compiled module in
use, a run never loads it (~0.1 s of every command's start-up).
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import logging
import re

import numpy as np

__all__ = ["MODULES", "Kernel", "compiled_module", "host_cpu", "kernel", "numba_njit",
           "parse_signature", "registered", "source_digest"]  # fmt: skip

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
_numba_state: list = []  # [numba.njit], once numba is imported and knows the Kernel type
#: One argument of a kernel's signature: a scalar type ("f8") or an array ("f8[:, ::1]").
_ARGUMENT = re.compile(r"^([a-z]+[0-9]+)(?:\[([:, 1]+)\])?$")
#: numba's scalar types in the signatures, as the argument checks read them.
_SCALAR_KINDS = {"b1": "bool", "i4": "int", "i8": "int", "f4": "real", "f8": "real"}


class Kernel:
    """A numba kernel: the install's compiled entry whose signature the arguments
    match, else numba's JIT (``.jit``, a dispatcher; ``.py_func``, the Python source).

    Inside another kernel it is typed as its dispatcher, so kernels call kernels.
    """

    def __init__(self, py_func, signatures: tuple[str, ...]):
        self.py_func = py_func
        self.signatures = signatures
        self.name = f"{py_func.__module__.rsplit('.', 1)[-1]}__{py_func.__name__}"
        self.__doc__, self.__name__ = py_func.__doc__, py_func.__name__
        self._call = self._first_call
        self._jit = None

    @property
    def jit(self):
        """numba's dispatcher of ``py_func``, made (numba imported) on first use."""
        if self._jit is None:
            self._jit = numba_njit()(cache=True, nogil=True, error_model="numpy")(self.py_func)
        return self._jit

    def _jit_call(self, *args):
        return self.jit(*args)

    def entry_names(self) -> list[str]:
        """The names of this kernel's compiled entries in ``_aot``, one per signature."""
        return [f"{self.name}__{i}" for i in range(len(self.signatures))]

    def __call__(self, *args):
        return self._call(*args)

    def _first_call(self, *args):
        aot = compiled_module()
        entries = [] if aot is None else [getattr(aot, n) for n in self.entry_names()]
        jit = self._jit_call if entries else self.jit
        self._call = _dispatcher(self.py_func, self.signatures, entries, jit)
        return self._call(*args)


def numba_njit():
    """numba's ``njit``, numba imported and taught that a :class:`Kernel` inside a
    kernel is typed as its dispatcher (so kernels call kernels)."""
    if not _numba_state:
        from numba import njit, types
        from numba.extending import typeof_impl

        @typeof_impl.register(Kernel)
        def _typeof_kernel(val, c):
            return types.Dispatcher(val.jit)

        _numba_state.append(njit)
    return _numba_state[0]


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


def host_cpu() -> str:
    """This machine's CPU as compiled code depends on it: vendor, family, model and
    feature flags from ``/proc/cpuinfo`` (Linux: no command loads LLVM to ask), else
    LLVM's host CPU name and features."""
    try:
        with open("/proc/cpuinfo") as f:
            first = f.read().split("\n\n", 1)[0]
    except OSError:
        first = ""
    fields = {k.strip(): v.strip() for k, _, v in (line.partition(":")
                                                     for line in first.splitlines())}
    cpu = [fields.get(k, "") for k in ("vendor_id", "cpu family", "model", "flags")]
    if all(cpu):
        return " ".join(cpu)
    import llvmlite.binding as llvm

    return f"{llvm.get_host_cpu_name()} {llvm.get_host_cpu_features().flatten()}"


def source_digest() -> int:
    """A 63-bit digest of :data:`MODULES`' source and this machine's CPU
    (:func:`host_cpu`; the build's code is for the CPU it ran on, as the JIT's): the
    compiled module's must equal it."""
    h = hashlib.sha256(host_cpu().encode())
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
        args = parse_signature(signature)
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


def parse_signature(signature: str) -> list[tuple[str, np.dtype, int, str]]:
    """The arguments of a kernel's signature in numba's notation (``"f8[:, ::1], i8"``),
    without numba: per argument (kind, dtype, ndim, layout), kind "array" (layout "C"
    where the last axis is ``::1``, else "A") or the scalar's "bool", "int", "real"
    (ndim 0, layout "")."""
    args, depth, start = [], 0, 0
    for i, ch in enumerate(signature + ","):
        depth += (ch == "[") - (ch == "]")
        if ch == "," and depth == 0:
            if signature[start:i].strip():
                args.append(signature[start:i].strip())
            start = i + 1
    out = []
    for arg in args:
        m = _ARGUMENT.match(arg)
        if m is None or (m.group(2) is None and m.group(1) not in _SCALAR_KINDS):
            raise TypeError(f"kernel signature {signature!r}: cannot read {arg!r}")
        dtype = np.dtype(m.group(1))
        if m.group(2) is None:
            out.append((_SCALAR_KINDS[m.group(1)], dtype, 0, ""))
            continue
        axes = [a.strip() for a in m.group(2).split(",")]
        if any(a not in (":", "::1") for a in axes) or "::1" in axes[:-1]:
            raise TypeError(f"kernel signature {signature!r}: cannot read {arg!r}")
        out.append(("array", dtype, len(axes), "C" if axes[-1] == "::1" else "A"))
    return out


def _check(name: str, t, dtype_name: str, env: dict) -> str:
    """A Python expression: whether the value ``name`` has the type ``t`` (an item of
    :func:`parse_signature`) exactly."""
    kind, dtype, ndim, layout = t
    if kind == "array":
        env[dtype_name] = dtype
        c = f" and {name}.flags.c_contiguous" if layout == "C" else ""
        return (f"type({name}) is ndarray and {name}.dtype == {dtype_name}"
                f" and {name}.ndim == {ndim}{c}")  # fmt: skip
    if kind == "bool":
        return f"isinstance({name}, bools)"
    if kind == "int":
        return f"isinstance({name}, ints) and not isinstance({name}, bools)"
    return f"isinstance({name}, reals)"
