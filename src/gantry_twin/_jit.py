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

import hashlib
import os
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numba
from numba.core.registry import CPUDispatcher

F = TypeVar("F", bound=Callable[..., Any])

#: The modules whose kernels call each other (paths relative to the package).
KERNEL_MODULES = (
    "_jit.py",
    "taskframe.py",
    "estimation.py",
    "controllers/law.py",
    "controllers/arc.py",
    "controllers/pd.py",
    "simulate.py",
    "monitor.py",
)


def cache_dir() -> str:
    """Where compiled kernels are cached: one directory per version of the kernel sources.

    numba invalidates a cached function only when *its own* file changes, not
    when a kernel it calls (in another file) does; keying the directory on a
    hash of every kernel module makes any edit recompile everything.
    NUMBA_CACHE_DIR, if set, is the parent; else ~/.cache/gantry_twin/numba.
    """
    package = Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for name in KERNEL_MODULES:
        digest.update((package / name).read_bytes())
    root = os.environ.get("NUMBA_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "gantry_twin", "numba"
    )
    return os.path.join(root, digest.hexdigest()[:16])


_CACHE_DIR = cache_dir()


def kernel(function: F) -> F:
    """Compile ``function`` in nopython mode, cached on disk under :func:`cache_dir`."""
    saved = numba.config.CACHE_DIR
    numba.config.CACHE_DIR = _CACHE_DIR  # read once, when the dispatcher's cache is created
    try:
        return numba.njit(cache=True)(function)  # type: ignore[return-value]
    finally:
        numba.config.CACHE_DIR = saved


def is_cached(function: Callable[..., Any]) -> bool:
    """True if a compiled version of kernel ``function`` is in the cache (its first call loads, not compiles)."""
    py = getattr(function, "py_func", function)
    pattern = f"{py.__module__.rsplit('.', 1)[-1]}.{py.__qualname__}-*.nbi"  # numba's index file of the function
    return any(Path(_CACHE_DIR).rglob(pattern))


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
