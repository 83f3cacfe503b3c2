"""Physical constants shared by the library, the simulator, the benchmarks and the tests:
each declared once, in fusion/_constants.pxd (which the kernels cimport); these are their
Python names.

The two values of gravity are two facts, not a disagreement: ``GRAVITY`` is the local gravity
every model of this project uses (the synthetic scenarios, the robot's world, the filters'
gravity reference and the numpy references), ``STANDARD_GRAVITY`` the unit "g" that sensor
datasheets quote accelerometer ranges, noise and bias in.
"""

from fusion._core import GRAVITY as _G, STANDARD_GRAVITY as _SG

GRAVITY: float = _G
"""m/s^2: the magnitude of gravity in every model here (a still, level accelerometer reads
+GRAVITY on its up axis)."""

STANDARD_GRAVITY: float = _SG
"""m/s^2 per g: standard gravity (3rd General Conference on Weights and Measures, 1901), the
"g" of datasheets."""

__all__ = ["GRAVITY", "STANDARD_GRAVITY"]
