"""Builds the Cython kernels of fusion/ (metadata lives in pyproject.toml)."""
import os
import platform
import sys
import sysconfig
from pathlib import Path

import numpy as np
from Cython.Build import cythonize
from setuptools import Extension, setup

# every fusion/_*.pyx and envs/_*.pyx is a kernel module
KERNELS = sorted(f"{p.parent.name}.{p.stem}" for pkg in ("fusion", "envs")
                 for p in Path(__file__).parent.glob(f"{pkg}/_*.pyx"))

# FUSION_MARCH: the -march the kernels are compiled for. Empty (default): the compiler's
# baseline for the platform (x86-64: SSE2; aarch64: armv8-a), so a wheel runs on every CPU
# its tag promises. "native": the building machine's instruction set, for a build that
# stays on that machine (make's editable install sets it): FMA and AVX2 gain the kernels
# 13-18 %, and such a build raises an illegal instruction on an older CPU.
MARCH = os.environ.get("FUSION_MARCH", "")
COMPILE_ARGS = ["-O3", "-fno-math-errno"] + ([f"-march={MARCH}"] if MARCH else [])
LINK_ARGS = []
CC = os.environ.get("CC") or sysconfig.get_config_var("CC") or ""
if sys.platform != "win32":
    # no debug info: Python's own CFLAGS carry -g, and the last -g flag wins
    COMPILE_ARGS.append("-g0")
if sys.platform.startswith("linux"):
    LINK_ARGS.append("-s")  # stripped at link: the .so files shrink about six-fold
if platform.machine().lower() in ("aarch64", "arm64") and "gcc" in CC:
    # Cython's reference counts of memoryviews are atomics: inline ARMv8.0 ones, not libgcc's
    # outline helpers, whose LSE paths (chosen at run time) a stripped file cannot tell apart
    # from code beyond the baseline (benchmarks/check_wheel_isa.py)
    COMPILE_ARGS.append("-mno-outline-atomics")
# GCC: inline a kernel's step into its batch loop even though the step is large and has a
# second caller (the per-sample path); a call per sample costs mahony 3 %, ekf 8 %
if "gcc" in CC:
    COMPILE_ARGS.append("--param=max-inline-insns-single=2000")

# The environment's step (envs/_signals and the IMU model it runs, fusion/_imu) must equal its
# numpy reference bit for bit: an episode is chaotic, so a last-bit difference in one step
# becomes a different episode. No fused multiply-add, then: -ffp-contract=off stops the
# contraction of a*b+c, and GCC's vectorisers still form vfmaddsub from paired adds and
# subtracts when -march has FMA (seen with x86-64-v3, GCC 12: the SLP vectoriser in straight
# code, the loop vectoriser in loops), so both are off for these kernels.
EXACT_KERNELS = {"envs._signals", "fusion._imu"}
EXACT_ARGS = ["-ffp-contract=off", "-fno-tree-vectorize"]

extensions = [
    Extension(name, [name.replace(".", "/") + ".pyx"],
              include_dirs=[np.get_include()],
              define_macros=[("NPY_NO_DEPRECATED_API", "NPY_1_7_API_VERSION")],
              extra_compile_args=COMPILE_ARGS + (EXACT_ARGS if name in EXACT_KERNELS else []),
              extra_link_args=LINK_ARGS)
    for name in KERNELS
]

setup(ext_modules=cythonize(
    extensions,
    compiler_directives={"language_level": 3, "boundscheck": False, "wraparound": False,
                         "cdivision": True, "initializedcheck": False},
))
