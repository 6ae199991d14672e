"""One run's instance of a controller FMU: unpacked, loaded, instantiated and initialised with fmpy; terminated,
freed and its temporary directory removed after the run (also a failed or interrupted one).

The loop calls the instance through the addresses :class:`Instance` gives (:mod:`gantry_twin.fmi.calls`);
everything else (instantiate, setupExperiment, the parameters, initialisation, terminate) goes through fmpy's
``FMU2Slave`` once per run. The FMU's log messages are kept (the last few name the cause of a failed call).
"""

from __future__ import annotations

import collections
import ctypes
import shutil
import tempfile
import weakref
import zipfile
from pathlib import Path
from typing import Any

from gantry_twin.fmi.calls import FMI2_ERROR, FMI2_FATAL, status_name
from gantry_twin.fmi.description import ControllerFmu, FmuError
from gantry_twin.loop.process import (
    CALL_TIMEOUT_S,
    MEMORY_LIMIT_BYTES,
    START_TIMEOUT_S,
    WorkerEnded,
    call_in_worker,
)
from gantry_twin.settings import shorten

#: How many of the FMU's log messages are kept for an error message.
LOG_KEPT = 4


def _remove(directory: str) -> None:
    shutil.rmtree(directory, ignore_errors=True)


class Instance:
    """An instantiated, initialised controller FMU (FMI 2.0 co-simulation) at time ``start_s``.

    ``addresses``: (fmi2SetReal, fmi2DoStep, fmi2GetReal, component) as integers. :meth:`close` ends it
    (fmi2Terminate, fmi2FreeInstance) and removes the unpacked files; FmuError if fmi2Terminate fails.
    """

    def __init__(self, fmu: ControllerFmu, start_s: float) -> None:
        self.fmu = fmu
        self.messages: collections.deque[str] = collections.deque(maxlen=LOG_KEPT)
        self.directory = tempfile.mkdtemp(prefix="gantry-twin-fmu-")
        # Removed when this object goes, or at the interpreter's exit (a SIGINT ends the program that way).
        self._cleanup = weakref.finalize(self, _remove, self.directory)
        self.slave: Any = None
        self.failed_status = 0
        try:
            self._start(start_s)
        except BaseException:
            self.close(terminate=False)
            raise

    def _start(self, start_s: float) -> None:
        from fmpy.fmi1 import FMICallException
        from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE

        fmu = self.fmu
        with zipfile.ZipFile(fmu.path) as archive:
            archive.extractall(self.directory)
        try:
            self.slave = FMU2Slave(
                guid=fmu.guid,
                unzipDirectory=self.directory,
                modelIdentifier=fmu.model_identifier,
                instanceName="controller",
            )
        except Exception as exc:  # a library that does not load, or lacks an FMI function
            why = _first_line(exc, unpacked=self.directory)
            raise FmuError(fmu.path, f"its binary cannot be loaded ({shorten(why.split('. ')[-1], 70)})") from None
        self.callbacks = fmi2CallbackFunctions()
        self.callbacks.logger = fmi2CallbackLoggerTYPE(self._log)
        from fmpy import calloc, free

        self.callbacks.allocateMemory = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.c_size_t, ctypes.c_size_t)(calloc)
        self.callbacks.freeMemory = ctypes.CFUNCTYPE(None, ctypes.c_void_p)(free)
        slave = self.slave
        try:
            slave.instantiate(callbacks=self.callbacks, loggingOn=False)
        except Exception:
            self.slave = None  # no component to free
            raise FmuError(fmu.path, f"fmi2Instantiate failed{self._said()}") from None
        try:
            slave.setupExperiment(startTime=start_s)
            for variable, value in fmu.parameters:
                slave.setReal([variable.value_reference], [value])
            slave.enterInitializationMode()
            slave.exitInitializationMode()
        except FMICallException as exc:
            raise FmuError(fmu.path, f"{exc.function} returned {status_name(exc.status)}{self._said()}") from None
        self.addresses = tuple(
            ctypes.cast(slave.dll[name], ctypes.c_void_p).value for name in ("fmi2SetReal", "fmi2DoStep", "fmi2GetReal")
        ) + (int(slave.component),)

    def _log(self, env: object, instance: bytes, status: int, category: bytes, message: bytes) -> None:
        text = (message or b"").decode("utf-8", "replace").strip()
        if text:
            self.messages.append(f"[{status_name(status)}] {text}")

    def _said(self) -> str:
        """'; the FMU logged: ...' with its last message, or ''."""
        return f"; the FMU logged: {shorten(self.messages[-1], 160)}" if self.messages else ""

    def why(self, call: str, status: int) -> str:
        """The line for a call that failed during the run, and remembers the status (close then skips what FMI 2.0
        forbids after it)."""
        self.failed_status = status
        return f"{self.fmu.path.name}: {call} returned {status_name(status)}{self._said()}"

    def close(self, terminate: bool = True) -> None:
        """fmi2Terminate (unless the FMU failed or ``terminate`` is False), fmi2FreeInstance (unless it was fatal),
        the unpacked files removed. FmuError if fmi2Terminate fails (the rest is done first)."""
        from fmpy.fmi1 import FMICallException

        slave, self.slave = self.slave, None
        problem = None
        try:
            if slave is not None and self.failed_status != FMI2_FATAL:
                if terminate and self.failed_status < FMI2_ERROR:
                    try:
                        slave.terminate()
                    except FMICallException as exc:
                        problem = f"fmi2Terminate returned {status_name(exc.status)}{self._said()}"
                slave.fmi2FreeInstance(slave.component)
                slave.freeLibrary()
        finally:
            self._cleanup()
        if problem is not None:
            raise FmuError(self.fmu.path, problem)


def trial_start(
    fmu: ControllerFmu, call_timeout_s: float = CALL_TIMEOUT_S, memory_limit_bytes: int = MEMORY_LIMIT_BYTES
) -> None:
    """Unpack, load, instantiate and initialise the FMU at t = 0, then end it and remove its files: FmuError if
    any of it fails (a binary that does not load, an instantiation or initialisation that fails), before a run.
    In a worker process (:func:`gantry_twin.loop.process.call_in_worker`): an FMU that crashes, exits, hangs (past
    ``call_timeout_s`` or 60 s, the longer) or leaks there is refused the same way."""
    try:
        call_in_worker(lambda: Instance(fmu, 0.0).close(), max(call_timeout_s, START_TIMEOUT_S), memory_limit_bytes)
    except WorkerEnded as exc:
        raise FmuError(fmu.path, f"its trial start (fmi2Instantiate to fmi2Terminate): {exc}") from None


def _first_line(exc: BaseException, unpacked: str | None = None) -> str:
    """The exception's first line, the ``unpacked`` directory's path taken out of it, shortened."""
    text = str(exc).strip()
    if not text:
        return type(exc).__name__
    line = text.splitlines()[0]
    if unpacked is not None:
        line = line.replace(f"{Path(unpacked).resolve()}/", "").replace(f"{unpacked}/", "")
    return shorten(line, 160)
