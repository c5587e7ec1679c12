"""The install compiles the numba kernels ahead of time (camwhisker/kernels), so
that a first run compiles nothing; the rest of the project is in pyproject.toml."""

import sys
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

AOT = "camwhisker.kernels._aot"


class BuildKernels(build_ext):
    """Builds the kernels with numba's AOT compiler; a failure leaves the JIT (a warning)."""

    def build_extension(self, ext):
        if ext.name != AOT:
            return super().build_extension(ext)
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from camwhisker.kernels.build import compile_kernels

        try:
            print(f"compiled kernels: {compile_kernels(Path(self.get_ext_fullpath(AOT))):.0f} s")
        except Exception as err:  # any failure: the package still works, on numba's JIT
            print(f"warning: camwhisker's kernels not compiled ({err}); numba's JIT instead")


setup(ext_modules=[Extension(AOT, sources=[])], cmdclass={"build_ext": BuildKernels})
