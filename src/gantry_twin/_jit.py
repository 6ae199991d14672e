"""One source for each equation: numba kernels and their plain-Python reference.

The per-sample equations (task frame, control law, filters, least squares,
projections) are written once, as small functions on floats and float64
arrays that write into preallocated outputs. :func:`kernel` compiles such a
function with numba (``cache=True``: compiled once per machine, then loaded
from ``__pycache__``). :func:`reference` returns the *same* code run by the
Python interpreter, with every kernel it calls also uncompiled, so the
compiled loop can be checked against an implementation numba never touched.

Kernels use ``math`` functions on scalars (the C library's sin/cos/atan/exp,
which numba calls too) rather than numpy ufuncs on scalars, so both versions
do the same floating-point operations in the same order.
"""

from __future__ import annotations

import types
from collections.abc import Callable
from typing import Any, TypeVar

import numba
from numba.core.registry import CPUDispatcher

F = TypeVar("F", bound=Callable[..., Any])


def kernel(function: F) -> F:
    """Compile ``function`` in nopython mode, cached on disk."""
    return numba.njit(cache=True)(function)  # type: ignore[return-value]


_reference_functions: dict[int, types.FunctionType] = {}
_reference_globals: dict[str, dict[str, Any]] = {}


def reference(function: Callable[..., Any]) -> Callable[..., Any]:
    """The uncompiled version of a kernel: same code, same callees, uncompiled."""
    py = getattr(function, "py_func", function)
    found = _reference_functions.get(id(py))
    if found is not None:
        return found
    ref = types.FunctionType(py.__code__, _globals_for(py.__globals__), py.__name__, py.__defaults__, py.__closure__)
    ref.__doc__, ref.__qualname__, ref.__module__ = py.__doc__, py.__qualname__, py.__module__
    _reference_functions[id(py)] = ref
    return ref


def _globals_for(module_globals: dict[str, Any]) -> dict[str, Any]:
    """A copy of a module's globals in which every kernel is its reference version."""
    name = module_globals["__name__"]
    env = _reference_globals.get(name)
    if env is None:
        env = dict(module_globals)
        _reference_globals[name] = env
        for key, value in module_globals.items():
            if isinstance(value, CPUDispatcher):
                env[key] = reference(value)
    return env
