"""One source for each equation: numba kernels and their plain-Python reference.

The per-sample equations (task frame, control law, filters, least squares,
projections) are written once, as small functions on floats and float64
arrays that write into preallocated outputs. :func:`kernel` compiles such a
function with numba (``cache=True``: compiled once per install path, machine
and version of the kernel sources, then loaded from :func:`cache_dir`).
:func:`reference` returns the *same* code run by the Python interpreter,
with every kernel it calls also uncompiled, so the compiled loop can be
checked against an implementation numba never touched.

:func:`kernel` with ``nrt=False`` compiles without numba's reference
counting: numba otherwise emits an atomic increment and decrement for every
array each time a nested tuple of settings, state and scratch arrays is
unpacked, passed or returned, which is most of the code it generates for the
loop (and an atomic operation per array per binding at run time). Such a
kernel may allocate no array; the arrays it receives from Python carry no
reference-count owner, so the kernels it calls count nothing either.

:func:`specialise` makes one copy of a template kernel per set of callees
named as globals (the compiled loop takes a controller's step this way), each
cached on disk under its own name.

Kernels use ``math`` functions on scalars (the C library's sin/cos/atan/exp,
which numba calls too) rather than numpy ufuncs on scalars, so both versions
do the same floating-point operations in the same order.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numba
from numba.core.registry import CPUDispatcher

F = TypeVar("F", bound=Callable[..., Any])


def kernel_sources(package: Path | None = None) -> list[Path]:
    """The package's modules that define kernels, and the package modules they import from.

    A kernel reads the globals it uses (constants, other kernels) when it is
    compiled, so the compiled code depends on these files and no others.
    """
    package = package or Path(__file__).resolve().parents[1]
    modules = {p.relative_to(package).with_suffix("").as_posix().replace("/", "."): p for p in package.rglob("*.py")}
    kernels = {name for name, path in modules.items() if "@kernel" in path.read_text(encoding="utf-8")}
    found = set(kernels)
    for name in kernels:
        for line in modules[name].read_text(encoding="utf-8").splitlines():
            words = line.split()
            if len(words) > 1 and words[0] == "from" and words[1].startswith("gantry_twin."):
                target = words[1].removeprefix("gantry_twin.")
                names = [w.strip(",()") for w in words[3:]] if len(words) > 3 and words[2] == "import" else []
                candidates = (target, f"{target}.__init__", *(f"{target}.{name}" for name in names))
                found.update(m for m in candidates if m in modules)
    return sorted(modules[name] for name in found)


def cache_dir() -> str:
    """Where compiled kernels are cached: one directory per version of the kernel sources.

    numba invalidates a cached function only when *its own* file changes, not
    when a kernel it calls (in another file) does; keying the directory on a
    hash of every kernel module makes any edit recompile everything.
    NUMBA_CACHE_DIR, if set, is the parent; else ~/.cache/gantry_twin/numba.
    """
    digest = hashlib.sha256()
    for path in kernel_sources():
        digest.update(path.read_bytes())
    root = os.environ.get("NUMBA_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "gantry_twin", "numba"
    )
    return os.path.join(root, digest.hexdigest()[:16])


_CACHE_DIR = cache_dir()


class CacheDirError(Exception):
    """The compiled-kernel cache cannot be made or written (one line naming NUMBA_CACHE_DIR)."""


def check_cache_dir() -> str:
    """The cache directory the kernels use, made and written to once (a temporary file), as numba will.

    CacheDirError if it cannot be: numba would then fall back, silently, to a
    folder beside the sources (or compile again in every process), and a
    sweep's workers could not take the compile lock. Root ignores permission
    bits, so a ``chmod 555`` folder is writable for root; a read-only file
    system or a path under a regular file is not.
    """
    where = "NUMBA_CACHE_DIR" if os.environ.get("NUMBA_CACHE_DIR") else "the default cache (NUMBA_CACHE_DIR unset)"
    try:
        os.makedirs(_CACHE_DIR, exist_ok=True)
        tempfile.TemporaryFile(dir=_CACHE_DIR).close()
    except OSError as exc:
        raise CacheDirError(
            f"{where}: the compiled-kernel cache {_CACHE_DIR} cannot be made or written ({exc.strerror or exc}); "
            "set NUMBA_CACHE_DIR to a writable folder",
        ) from None
    return _CACHE_DIR


def kernel(
    function: F | None = None, *, inline: bool = False, internal: bool = False, nrt: bool = True, nogil: bool = False
) -> Any:
    """Compile ``function`` in nopython mode, cached on disk under :func:`cache_dir`.

    Each kernel compiles once per argument types and is cached on its own,
    so the loops of several controllers share what they call (the plant's
    half of the loop, the law, the linear algebra) instead of compiling it
    into each. ``@kernel(inline=True)``: numba inlines the function's code
    into each caller, re-typing it there; only for small glue and leaf kernels
    (a few lines), where a compile of its own (and a call with every array of
    the tuples as separate arguments) costs more. ``internal=True``: no
    Python entry point (numba's CPython wrapper, which unboxes every array of
    the nested tuples): for kernels that only other kernels call.
    docs/performance.md ("Compile") has the measurements behind this split.
    No kernel gets numba's C-callable wrapper (only first-class function
    values need it). ``nrt=False``: no reference counting (see the module
    docstring); numba refuses to compile such a kernel if it allocates.
    ``nogil=True``: the kernel releases Python's interpreter lock while it
    runs, so that other threads of the process (the live link's server) run
    beside it on another core instead of waiting for it to return.
    """
    if function is None:
        return lambda f: kernel(f, inline=inline, internal=internal, nrt=nrt, nogil=nogil)
    saved = numba.config.CACHE_DIR
    numba.config.CACHE_DIR = _CACHE_DIR  # read once, when the dispatcher's cache is created
    try:
        # _nrt explicit: numba otherwise inherits it from the first caller that compiles the kernel.
        options: dict[str, bool] = {"_nrt": nrt, "no_cpython_wrapper": True} if internal else {"_nrt": nrt}
        if nogil:
            options["nogil"] = True
        return numba.njit(cache=True, inline="always" if inline else "never", no_cfunc_wrapper=True, **options)(
            function
        )
    finally:
        numba.config.CACHE_DIR = saved


def is_cached(function: Callable[..., Any]) -> bool:
    """True if numba's cache holds kernel ``function`` compiled for this install and machine (its first call loads).

    Asks the kernel's own numba cache, as its first call will: the index
    file under the folder numba derives from the source file's path, valid
    only for the source's current content (numba keeps its hash), with an
    entry for this machine's code generator and this bytecode. Another
    install of the package (another path) or an edited file has no entry
    and compiles. Any argument types count (a loop's types are fixed by its
    controller's step).
    """
    try:
        cache = function._cache
        codegen = function.targetctx.codegen()
        wanted = cache._index_key(None, codegen)[1:]  # (machine, (bytecode hash, closure hash)); [0]: the signature
        return any(key[1:] == wanted for key in cache._cache_file._load_index())
    except (AttributeError, TypeError, OSError):  # not a cached kernel, or numba's internals changed: assume a compile
        return False


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


def specialise(
    template: Callable[..., Any],
    name: str,
    bindings: dict[str, Any],
    compiled: bool,
    nrt: bool = True,
    nogil: bool = False,
) -> Callable[..., Any]:
    """A copy of kernel ``template`` whose globals ``bindings`` (name -> kernel or value) are replaced.

    compiled: a kernel cached on disk as ``<template>_<name>`` (``name``
    must identify the bindings, e.g. with a digest of their sources: numba
    keys its cache on the template's code and argument types only);
    otherwise the reference version, with every other kernel uncompiled.
    nrt, nogil: as for :func:`kernel`.
    """
    py = getattr(template, "py_func", template)
    env = dict(py.__globals__ if compiled else _globals_for(py.__globals__))
    env.update(bindings)
    function = types.FunctionType(py.__code__, env, py.__name__, py.__defaults__, py.__closure__)
    function.__qualname__ = f"{py.__qualname__}_{name}"
    function.__doc__, function.__module__ = py.__doc__, py.__module__
    return kernel(function, nrt=nrt, nogil=nogil) if compiled else function


def source_digest(*functions: Callable[..., Any]) -> str:
    """A short digest of ``functions`` (kernels or plain functions): their code and their source files."""
    digest = hashlib.sha256()
    for function in functions:
        py = getattr(function, "py_func", function)
        digest.update(py.__module__.encode() + b":" + py.__qualname__.encode())
        digest.update(_code_bytes(py.__code__))  # also for functions without a file (a notebook)
        try:
            digest.update(Path(py.__code__.co_filename).read_bytes())
        except OSError:
            pass
    return digest.hexdigest()[:12]


def _code_bytes(code: types.CodeType) -> bytes:
    """The bytecode, names and constants of a code object, nested functions included (stable across processes)."""
    parts = [code.co_code, repr(code.co_names).encode()]
    for const in code.co_consts:
        parts.append(_code_bytes(const) if isinstance(const, types.CodeType) else repr(const).encode())
    return b"\0".join(parts)
