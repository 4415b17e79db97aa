"""Builds the optional C cost kernel; everything else is declared in pyproject.toml.

The kernel (src/formation_bench/mpc/_cost_kernel.c) is compiled for the machine it is
installed on, with the first set of flags the compiler accepts. Without a working C
compiler the package installs without it and uses the numba kernel, which computes the
same numbers (formation_bench.mpc.native_cost). FORMATION_BENCH_CFLAGS replaces the
flags (for instance "-O3 -mavx2 -mfma -ffp-contract=off" for a wheel that other
machines install); the kernel is correct only with -ffp-contract=off.
"""

from __future__ import annotations

import os
import shlex

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

# -ffp-contract=off: no multiply-add is fused but the ones the source writes, so that the
# C kernel and the numba kernel round alike; -fno-math-errno lets sqrt vectorise (it sets
# no errno, and its result is the same)
COMMON = ["-O3", "-ffp-contract=off", "-fno-math-errno", "-std=c11"]
FLAG_SETS = [
    [*COMMON, "-march=native"],
    [*COMMON, "-mcpu=native"],
    COMMON,
]


class BuildCostKernel(build_ext):
    """build_ext that tries the flag sets in turn and leaves the kernel out if none builds."""

    def build_extension(self, ext: Extension) -> None:
        chosen = os.environ.get("FORMATION_BENCH_CFLAGS")
        candidates = [shlex.split(chosen)] if chosen else FLAG_SETS
        for flags in candidates:
            ext.extra_compile_args = flags
            try:
                super().build_extension(ext)
            except Exception as error:  # any compiler failure: try the next flags
                print(f"formation-bench: the C cost kernel did not build with {flags}: {error}")
                continue
            print(f"formation-bench: built the C cost kernel with {' '.join(flags)}")
            return
        print(
            "formation-bench: no C cost kernel (no working C compiler); the numba kernel, "
            "which gives the same numbers, is used instead"
        )


setup(
    ext_modules=[
        Extension(
            "formation_bench.mpc._cost_kernel",
            sources=["src/formation_bench/mpc/_cost_kernel.c"],
            optional=True,
        )
    ],
    cmdclass={"build_ext": BuildCostKernel},
)
