"""Builds the Cython kernels of fusion/ (metadata lives in pyproject.toml)."""
from pathlib import Path

import numpy as np
from Cython.Build import cythonize
from setuptools import Extension, setup

# every fusion/_*.pyx is a kernel module
KERNELS = sorted(p.stem for p in Path(__file__).parent.glob("fusion/_*.pyx"))

extensions = [
    Extension(f"fusion.{name}", [f"fusion/{name}.pyx"],
              include_dirs=[np.get_include()],
              define_macros=[("NPY_NO_DEPRECATED_API", "NPY_1_7_API_VERSION")],
              extra_compile_args=["-O3", "-fno-math-errno"])
    for name in KERNELS
]

setup(ext_modules=cythonize(
    extensions,
    compiler_directives={"language_level": 3, "boundscheck": False, "wraparound": False,
                         "cdivision": True, "initializedcheck": False},
))
