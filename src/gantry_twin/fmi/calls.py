"""The three FMI 2.0 calls of a sample, by address: ``fmi2SetReal``, ``fmi2DoStep``, ``fmi2GetReal``.

A native FMU's shared library is loaded once per run (:mod:`gantry_twin.fmi.instance`); its entry points and
its component are plain integers (addresses), passed to the loop as runtime arguments, never compiled in, so
numba's on-disk cache of the loop holds for every FMU and every run. Each call is one Python function (ctypes:
the reference loop) with a numba overload that casts the address to a C function pointer and calls it (the
compiled loop: no Python per sample). Both return the call's ``fmi2Status``.

The C signatures (``fmi2FunctionTypes.h`` of the FMI 2.0 standard):

    fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]);
    fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]);
    fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                          fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint);

with ``fmi2Status`` and ``fmi2Boolean`` C ints, ``fmi2ValueReference`` an unsigned int, ``fmi2Real`` a double.
"""

from __future__ import annotations

import ctypes
import functools

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic, overload

#: fmi2Status values (fmi2TypesPlatform.h).
FMI2_OK, FMI2_WARNING, FMI2_DISCARD, FMI2_ERROR, FMI2_FATAL, FMI2_PENDING = range(6)
STATUS_NAMES = ("fmi2OK", "fmi2Warning", "fmi2Discard", "fmi2Error", "fmi2Fatal", "fmi2Pending")
#: fmi2True: the loop never sets an FMU's state back (noSetFMUStatePriorToCurrentPoint).
FMI2_TRUE = 1


def status_name(status: int) -> str:
    """``fmi2Error`` for 3; an unknown code as ``status 17``."""
    return STATUS_NAMES[status] if 0 <= status < len(STATUS_NAMES) else f"status {status}"


_REAL_ARRAY = ctypes.CFUNCTYPE(
    ctypes.c_int, ctypes.c_void_p, ctypes.POINTER(ctypes.c_uint), ctypes.c_size_t, ctypes.POINTER(ctypes.c_double)
)
_DO_STEP = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_double, ctypes.c_double, ctypes.c_int)


@functools.lru_cache(maxsize=64)
def _real_array_function(address: int) -> ctypes._CFuncPtr:
    return _REAL_ARRAY(address)


@functools.lru_cache(maxsize=64)
def _do_step_function(address: int) -> ctypes._CFuncPtr:
    return _DO_STEP(address)


def _real_array_call(function: int, component: int, vr: np.ndarray, n: int, values: np.ndarray) -> int:
    return int(
        _real_array_function(function)(
            component,
            vr.ctypes.data_as(ctypes.POINTER(ctypes.c_uint)),
            n,
            values.ctypes.data_as(ctypes.POINTER(ctypes.c_double)),
        )
    )


def set_real(function: int, component: int, vr: np.ndarray, n: int, values: np.ndarray) -> int:
    """``fmi2SetReal(component, vr, n, values)`` at address ``function``; vr uint32, values float64."""
    return _real_array_call(function, component, vr, n, values)


def get_real(function: int, component: int, vr: np.ndarray, n: int, values: np.ndarray) -> int:
    """``fmi2GetReal(component, vr, n, values)`` at address ``function``, into ``values`` (float64)."""
    return _real_array_call(function, component, vr, n, values)


def do_step(function: int, component: int, t_s: float, h_s: float) -> int:
    """``fmi2DoStep(component, t_s, h_s, fmi2True)`` at address ``function``."""
    return int(_do_step_function(function)(component, t_s, h_s, FMI2_TRUE))


# -- the compiled calls ------------------------------------------------------------------------------------------

_I8P = ir.IntType(8).as_pointer()
_I32 = ir.IntType(32)
_I64 = ir.IntType(64)
_DOUBLE = ir.DoubleType()


@intrinsic
def _call_real_array(typingctx, function, component, vr, n, values):  # noqa: ARG001 -- numba's signature
    """Call ``fmi2Status f(void*, const unsigned*, size_t, double*)`` at the address ``function``."""
    sig = types.int32(types.int64, types.int64, vr, types.int64, values)

    def codegen(context, builder, signature, args):
        f, c, vr_array, count, value_array = args
        vr_data = context.make_array(signature.args[2])(context, builder, value=vr_array).data
        value_data = context.make_array(signature.args[4])(context, builder, value=value_array).data
        fnty = ir.FunctionType(_I32, [_I8P, _I32.as_pointer(), _I64, _DOUBLE.as_pointer()])
        callee = builder.inttoptr(f, fnty.as_pointer())
        return builder.call(
            callee,
            [
                builder.inttoptr(c, _I8P),
                builder.bitcast(vr_data, _I32.as_pointer()),
                count,
                builder.bitcast(value_data, _DOUBLE.as_pointer()),
            ],
        )

    return sig, codegen


@intrinsic
def _call_do_step(typingctx, function, component, t_s, h_s):  # noqa: ARG001 -- numba's signature
    """Call ``fmi2Status f(void*, double, double, int)`` at the address ``function`` (the last argument fmi2True)."""
    sig = types.int32(types.int64, types.int64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        f, c, t, h = args
        fnty = ir.FunctionType(_I32, [_I8P, _DOUBLE, _DOUBLE, _I32])
        callee = builder.inttoptr(f, fnty.as_pointer())
        return builder.call(callee, [builder.inttoptr(c, _I8P), t, h, ir.Constant(_I32, FMI2_TRUE)])

    return sig, codegen


def _check_real_array(vr: types.Type, values: types.Type) -> bool:
    return (
        isinstance(vr, types.Array)
        and vr.dtype == types.uint32
        and vr.layout == "C"
        and isinstance(values, types.Array)
        and values.dtype == types.float64
        and values.layout == "C"
    )


@overload(set_real, inline="always")
def _set_real_compiled(function, component, vr, n, values):
    if _check_real_array(vr, values):
        return lambda function, component, vr, n, values: _call_real_array(function, component, vr, n, values)
    return None


@overload(get_real, inline="always")
def _get_real_compiled(function, component, vr, n, values):
    if _check_real_array(vr, values):
        return lambda function, component, vr, n, values: _call_real_array(function, component, vr, n, values)
    return None


@overload(do_step, inline="always")
def _do_step_compiled(function, component, t_s, h_s):
    return lambda function, component, t_s, h_s: _call_do_step(function, component, t_s, h_s)
