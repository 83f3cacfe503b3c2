"""Builds the Cython kernels of fusion/ (metadata lives in pyproject.toml)."""
import os
import sysconfig
from pathlib import Path

import numpy as np
from Cython.Build import cythonize
from setuptools import Extension, setup

# every fusion/_*.pyx and envs/_*.pyx is a kernel module
KERNELS = sorted(f"{p.parent.name}.{p.stem}" for pkg in ("fusion", "envs")
                 for p in Path(__file__).parent.glob(f"{pkg}/_*.pyx"))

# FUSION_MARCH: the -march the kernels are compiled for. "native" (default): the machine that
# builds them runs them (make install, make test), and the kernels gain 13-18 % from its
# instruction set (FMA); set it empty (FUSION_MARCH=) for a portable build, a wheel for others.
MARCH = os.environ.get("FUSION_MARCH", "native")
COMPILE_ARGS = ["-O3", "-fno-math-errno"] + ([f"-march={MARCH}"] if MARCH else [])
# GCC: inline a kernel's step into its batch loop even though the step is large and has a
# second caller (the per-sample path); a call per sample costs mahony 3 %, ekf 8 %
if "gcc" in (os.environ.get("CC") or sysconfig.get_config_var("CC") or ""):
    COMPILE_ARGS.append("--param=max-inline-insns-single=2000")

extensions = [
    Extension(name, [name.replace(".", "/") + ".pyx"],
              include_dirs=[np.get_include()],
              define_macros=[("NPY_NO_DEPRECATED_API", "NPY_1_7_API_VERSION")],
              extra_compile_args=COMPILE_ARGS)
    for name in KERNELS
]

setup(ext_modules=cythonize(
    extensions,
    compiler_directives={"language_level": 3, "boundscheck": False, "wraparound": False,
                         "cdivision": True, "initializedcheck": False},
))
