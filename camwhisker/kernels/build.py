"""Compile every kernel ahead of time into ``camwhisker/kernels/_aot`` (``setup.py`` runs it).

Only the install imports this module (numba's ``pycc``, deprecated but present in
numba 0.68); ``python -m camwhisker.kernels.build DIR`` builds into DIR by hand.
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

from camwhisker.kernels import AOT_MODULE, numba_njit, registered, source_digest


def compile_kernels(output: Path) -> float:
    """Build the compiled module at ``output`` (its file name with the extension suffix);
    returns the seconds it took."""
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # pycc's pending deprecation: it is what builds here
        from numba.pycc import CC, compiler
    compiler.Flags = _KernelFlags
    numba_njit()  # kernels that call kernels: numba must know the Kernel type
    cc = CC(AOT_MODULE.rsplit(".", 1)[-1])
    cc.output_dir, cc.output_file = str(output.parent), output.name
    # This CPU's instructions, as the JIT's (generic x86-64 code runs some kernels ~20%
    # slower); the digest holds the CPU, so that another machine uses the JIT instead.
    cc.target_cpu = "host"
    for k in registered():
        for signature, name in zip(k.signatures, k.entry_names(), strict=True):
            cc.export(name, signature)(k.py_func)
    digest = source_digest()
    cc.export("source_digest", "()")(lambda: digest)
    output.parent.mkdir(parents=True, exist_ok=True)
    cc.compile()
    return time.perf_counter() - t0


class _KernelFlags:
    """pycc's compile flags with the JIT's options (``kernel``): numpy's error model
    (x / 0 is inf or nan, not an exception) and the GIL released."""

    def __new__(cls):
        from numba.core.compiler import Flags

        flags = Flags()
        flags.error_model, flags.release_gil = "numpy", True
        return flags


if __name__ == "__main__":
    import sysconfig

    out = Path(sys.argv[1]) / ("_aot" + sysconfig.get_config_var("EXT_SUFFIX"))
    print(f"{out}: {compile_kernels(out):.1f} s")
