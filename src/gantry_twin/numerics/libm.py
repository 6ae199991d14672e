"""Elementwise sin, cos and atan2 through the C library: the same bits on every x86-64 CPU.

numpy evaluates its transcendental ufuncs on float64 arrays with SIMD loops
chosen at run time by the CPU's vector extensions (on AVX-512 machines, for
instance, arctan2 comes from vendor approximations), so their last bits
differ from one machine to another. The twin's traces are pinned to the bit
(tests/test_pinned_traces.py), and the compiled loop's kernels call the C
library's ``sin``, ``cos``, ``atan2`` (as ``math`` does): the reference
arrays the loop reads (desired position, tangent angle) are computed here
the same way, so a run gives the same trace on every machine.

Each function takes arrays (or numbers) that broadcast like numpy's and
returns a float64 array of their broadcast shape.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np


def _elementwise(function: Callable[..., float], *values: np.ndarray | float) -> np.ndarray:
    arrays = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in values))
    shape, size = arrays[0].shape, arrays[0].size
    columns = [a.ravel().tolist() for a in arrays]
    return np.fromiter(map(function, *columns), dtype=np.float64, count=size).reshape(shape)


def sin(x: np.ndarray | float) -> np.ndarray:
    """sin(x), x in rad, elementwise (the C library's ``sin``)."""
    return _elementwise(math.sin, x)


def cos(x: np.ndarray | float) -> np.ndarray:
    """cos(x), x in rad, elementwise (the C library's ``cos``)."""
    return _elementwise(math.cos, x)


def atan2(y: np.ndarray | float, x: np.ndarray | float) -> np.ndarray:
    """atan2(y, x) in rad, elementwise (the C library's ``atan2``; numpy's ``arctan2`` argument order)."""
    return _elementwise(math.atan2, y, x)
