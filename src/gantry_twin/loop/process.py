"""A forked worker process of the command's: made, watched and ended (:mod:`gantry_twin.loop.worker` runs the
loop in one; :func:`call_in_worker` runs one function in one).

A worker ignores the stop signals (the command ends it, at once), dies with the command (``PR_SET_PDEATHSIG``),
prints no stack on a crash (the command says in one line what ended it), keeps its temporary files in a directory
of its own that the command removes whatever the worker did, and may grow its address space by at most twice its
memory limit. The command's process watches it: what ended it (a signal, an exit status), a time limit, its
resident memory.
"""

from __future__ import annotations

import contextlib
import ctypes
import faulthandler
import gc
import mmap
import os
import pickle
import resource
import select
import shutil
import signal
import socket
import tempfile
import time
from collections.abc import Callable
from typing import Any

#: How often the command's process looks at a worker that has not answered, s (the stop signals are seen at once).
WATCH_S = 0.02
#: The time limit of the controller's start in the worker (an FMU unpacked and instantiated), s, if longer than
#: its call's limit.
START_TIMEOUT_S = 60.0
#: Defaults of a hosted controller's limits: wall time per call, s; resident memory, bytes (docs/fmi.md).
CALL_TIMEOUT_S = 10.0
MEMORY_LIMIT_BYTES = 2048 << 20
#: The signals the command turns into an exception; the worker ignores them (the command ends it).
_STOP_SIGNALS = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n))
_PR_SET_PDEATHSIG = 1


#: The prefix of a worker's temporary directory, the command's pid after it.
SCRATCH_PREFIX = "gantry-twin-worker-"
_stale_removed = False


def scratch_directory() -> str:
    """A new temporary directory for a worker, named after this process; the first one also removes those of
    commands that are gone (killed by SIGKILL: nothing of theirs could remove them)."""
    global _stale_removed
    if not _stale_removed:
        _stale_removed = True
        with contextlib.suppress(OSError):
            for entry in os.scandir(tempfile.gettempdir()):
                owner = entry.name[len(SCRATCH_PREFIX) :].split("-", 1)[0]
                if entry.name.startswith(SCRATCH_PREFIX) and owner.isdigit() and not _alive(int(owner)):
                    shutil.rmtree(entry.path, ignore_errors=True)
    return tempfile.mkdtemp(prefix=f"{SCRATCH_PREFIX}{os.getpid()}-")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's: alive
        return True
    return True


def how_it_ended(status: int) -> str:
    """'its process was killed by SIGSEGV (Segmentation fault)', or 'its process exited with status 3'."""
    if os.WIFSIGNALED(status):
        number = os.WTERMSIG(status)
        return f"its process was killed by {signal.Signals(number).name} ({signal.strsignal(number)})"
    return f"its process exited with status {os.waitstatus_to_exitcode(status)}"


class WorkerEnded(RuntimeError):
    """A worker of :func:`call_in_worker` crashed, exited, hung past its limit or passed its memory limit."""


def call_in_worker(function: Callable[[], Any], limit_s: float, memory_limit_bytes: int = MEMORY_LIMIT_BYTES) -> Any:
    """``function()`` in a forked worker process, watched as a :class:`WorkerLoop` is: its value (it must pickle),
    or its exception raised here; :class:`WorkerEnded` ("its process was killed by SIGSEGV (...)", "did not
    return within S s", ...) if it crashes, exits, takes more than ``limit_s`` of wall time or passes
    ``memory_limit_bytes`` resident. A stop signal here kills it at once. Run in this process where processes
    cannot be forked."""
    if not hasattr(os, "fork"):
        return function()
    scratch = scratch_directory()
    ours, theirs = socket.socketpair()
    pid = 0
    try:
        parent = os.getpid()
        pid = os.fork()
        if pid == 0:
            code = 0
            try:
                ours.close()
                become_worker(memory_limit_bytes, scratch, parent)
                theirs.sendall(pickle.dumps(("done", function())))
            except BaseException as exc:  # noqa: BLE001 -- the worker's errors are the caller's to raise
                with contextlib.suppress(BaseException):
                    theirs.sendall(pickle.dumps(("raise", sendable(exc))))
                code = 1
            finally:
                os._exit(code)
        theirs.close()
        deadline = time.monotonic() + limit_s
        answer = b""
        while True:
            ready = select.select([ours], [], [], WATCH_S)[0]
            if ready:
                data = ours.recv(1 << 16)
                if data:
                    answer += data
                    continue
                break  # the worker closed its end: done, or gone
            if time.monotonic() > deadline:
                raise WorkerEnded(f"did not return within {limit_s:g} s (its time limit); stopped")
            if (resident := resident_bytes(pid)) > memory_limit_bytes:
                raise WorkerEnded(
                    f"its process passed its memory limit of {memory_limit_bytes / 2**20:.0f} MiB "
                    f"({resident / 2**20:.0f} MiB resident); stopped"
                )
        status = os.waitpid(pid, 0)[1]
        pid = 0
        if not answer:
            raise WorkerEnded(how_it_ended(status))
        kind, value = pickle.loads(answer)
        if kind == "raise":
            raise value
        return value
    finally:
        ours.close()
        theirs.close()
        if pid > 0:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
            with contextlib.suppress(ChildProcessError):
                os.waitpid(pid, 0)
        shutil.rmtree(scratch, ignore_errors=True)


def resident_bytes(pid: int) -> int:
    """The resident memory of process ``pid``, bytes (0 if it is gone)."""
    try:
        with open(f"/proc/{pid}/statm", "rb") as fh:
            return int(fh.read().split()[1]) * mmap.PAGESIZE
    except (OSError, IndexError, ValueError):
        return 0


def _address_space_bytes() -> int:
    with open("/proc/self/statm", "rb") as fh:
        return int(fh.read().split()[0]) * mmap.PAGESIZE


def become_worker(memory_limit_bytes: int, scratch: str, parent: int) -> None:
    """Stop signals ignored (the command, ``parent``, ends the worker), ended with the command, no stack dump and no
    core on a crash (the command says what happened, in one line), temporary files in ``scratch``, address space
    bounded."""
    gc.disable()
    for number in _STOP_SIGNALS:
        signal.signal(number, signal.SIG_IGN)
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent:  # the command ended before the death signal was asked for
        os._exit(1)
    faulthandler.disable()
    tempfile.tempdir = scratch
    os.environ["TMPDIR"] = scratch
    limit = _address_space_bytes() + 2 * memory_limit_bytes
    with contextlib.suppress(ValueError, OSError):
        soft, hard = resource.getrlimit(resource.RLIMIT_AS)
        if hard == resource.RLIM_INFINITY or hard > limit:
            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    with contextlib.suppress(ValueError, OSError):  # foreign code that crashes dumps no core of this process
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))  # (hundreds of MB) into the user's directory


def sendable(exc: BaseException) -> BaseException:
    """``exc`` if it pickles whole (a ScenarioError, an FmuError), else a RuntimeError with its line."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # noqa: BLE001 -- anything that does not survive the pipe
        text = str(exc).splitlines()[0] if str(exc) else ""
        return RuntimeError(f"{type(exc).__name__}: {text}" if text else type(exc).__name__)
