"""Units and array types, one place for the whole project.

Radians, metres, seconds and SI inside; degrees and datasheet units only at the edges, converted
with these factors (``x_rad = x_deg * DEG``, ``bias_radps = bias_deg_h * DEG_PER_H``).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

#: float64 array of any shape; docstrings give the shape.
FloatArray = NDArray[np.float64]
#: int64 array (e.g. stamps in ns).
IntArray = NDArray[np.int64]

#: one degree in radians.
DEG = math.pi / 180.0
#: one degree per hour in rad/s (gyro bias, datasheet unit).
DEG_PER_H = DEG / 3600.0
#: standard gravity [m/s^2] (CGPM 1901), the "g" of accelerometer datasheets.
G0_MPS2 = 9.80665
#: one micro-g in m/s^2 (accelerometer bias, datasheet unit): G0_MPS2 * 1e-6, written out (the
#: float product differs from the literal in its last bit, and the simulator's noise is seeded on it).
UG_MPS2 = 9.80665e-6

__all__ = ["FloatArray", "IntArray", "DEG", "DEG_PER_H", "G0_MPS2", "UG_MPS2"]
