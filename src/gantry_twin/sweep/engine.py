"""Running many independent runs on Dask distributed: a LocalCluster, or a running cluster by address.

The same code serves a laptop and a cluster (docs/sweeps.md): a
``LocalCluster`` of one single-threaded worker *process* per core (the
compiled loop holds the GIL, so threads would queue on it), or
``Client("tcp://host:8786")``. Tasks are submitted impure (``pure=False``):
two runs of the same arguments are two tasks, and anything random travels
in the arguments as an explicit seed. A worker that dies has its tasks
rescheduled by Dask; the caller sees each task's result (or error) once.

numba's on-disk cache is not safe when several processes compile into it
at once, so each worker process compiles (or loads) the loop of each
controller it will run once, before the runs, in a short warm-up run held
under a file lock beside the cache (:func:`warm_up`): one worker compiles,
the others wait and then load what it wrote.
"""

from __future__ import annotations

import contextlib
import json
import logging
import multiprocessing
import os
import re
import socket
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import replace
from typing import Any

from gantry_twin.numerics.jit import cache_dir
from gantry_twin.run import execute, package_version
from gantry_twin.scenario import Scenario, build, validate_data

try:  # POSIX; elsewhere warm-ups are not serialised
    import fcntl
except ImportError:  # pragma: no cover
    fcntl = None  # type: ignore[assignment]

#: Simulated time of a warm-up run, s: long enough to call every kernel of the loop once.
WARM_UP_S = 0.01
#: How long to wait for a scheduler to answer, and for a connected cluster to have a worker, s.
CONNECT_TIMEOUT_S = 10.0
WORKERS_TIMEOUT_S = 60.0
#: How long each worker of a LocalCluster may take to start (its process up and registered), s: Dask's
#: ``death_timeout`` of the workers' nannies (a worker stuck at start once kept ``sweep`` waiting for ever).
CLUSTER_START_TIMEOUT_S = 120.0
#: How long the workers may take to compile or load the loops before the first run (:func:`prepare_workers`), s:
#: a first compile of a loop takes about a minute on a loaded 2-core machine, and they queue on the compile lock.
WARM_UP_TIMEOUT_S = 1200.0
#: A scheduler's handshake is a few hundred bytes; a first frame announced longer is not one.
HANDSHAKE_MAX_BYTES = 1 << 20
COMPILE_LOCK = ".compile.lock"
#: Tasks submitted ahead per worker thread: every worker has its next point queued, the rest wait in the driver.
IN_FLIGHT_PER_THREAD = 3


class ClusterError(RuntimeError):
    """The cluster cannot take the work: no scheduler at the address, no worker, a worker of another version."""


# ---------------------------------------------------------------------------
# On the workers.

_warmed: set[str] = set()


#: How deep this thread is in :func:`compile_lock` (the lock is taken by the outermost only).
_lock_depth = threading.local()


@contextlib.contextmanager
def compile_lock() -> Iterator[None]:
    """An exclusive lock on this machine's kernel cache (a file lock, so it holds across processes).

    Reentrant within a thread: ``gantry-twin compile`` holds it while its short run compiles, and whatever
    takes it around each compile then does not wait on its own lock (a second ``flock`` on a new open file of
    the same process blocks like another process's)."""
    if getattr(_lock_depth, "depth", 0):
        _lock_depth.depth += 1
        try:
            yield
        finally:
            _lock_depth.depth -= 1
        return
    directory = cache_dir()
    try:
        os.makedirs(directory, exist_ok=True)
        handle = open(os.path.join(directory, COMPILE_LOCK), "a")  # noqa: SIM115 (closed below)
    except OSError as exc:  # e.g. NUMBA_CACHE_DIR under a regular file, or read-only: the point fails, saying so
        raise OSError(
            exc.errno,
            f"the compiled-kernel cache {directory} cannot be made or locked ({exc.strerror}); "
            "set NUMBA_CACHE_DIR to a writable folder",
        ) from None
    with handle:
        if fcntl is not None:
            fcntl.flock(handle, fcntl.LOCK_EX)
        _lock_depth.depth = 1
        try:
            yield
        finally:
            _lock_depth.depth = 0
            if fcntl is not None:
                fcntl.flock(handle, fcntl.LOCK_UN)


def warm_up(scenario: Scenario, source: str = "<scenario>") -> bool:
    """Compile or load this process's loop for the scenario's controller, under :func:`compile_lock`.

    Once per process and controller (name and options: they fix the
    kernel's argument types); returns True if it ran. A warm-up that fails
    is ignored: the run itself will report the problem.
    """
    tag = json.dumps([scenario.controller.name, scenario.controller.options, scenario.monitor.enable], default=str)
    if tag in _warmed:
        return False
    built = build(scenario, source)
    short = replace(built, scenario=scenario.model_copy(update={"duration_s": WARM_UP_S}))
    with compile_lock():
        with contextlib.suppress(Exception):
            execute(short)
    _warmed.add(tag)
    return True


def _warm_up_all(resolved: Sequence[dict[str, Any]], source: str) -> int:
    """Warm up every controller of a sweep (a task pinned to one worker); returns how many ran."""
    return sum(warm_up(validate_data(r, source), source) for r in resolved)


def worker_versions() -> dict[str, str]:
    """What a worker runs (compared with the driver's before a sweep)."""
    import platform

    return {"gantry_twin": package_version(), "python": platform.python_version()}


# ---------------------------------------------------------------------------
# On the driver.


#: The address forms ``--scheduler`` takes: ``[protocol://]host:port`` (Dask's protocols over a network).
_ADDRESS = re.compile(r"(?:(?:tcp|tls|ws|wss|ucx)://)?(?:\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9._-]+):[0-9]{1,5}")


def machine_cores() -> int:
    """The cores this process may run on (its CPU affinity where the system says, else os.cpu_count())."""
    try:
        return len(os.sched_getaffinity(0)) or 1
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def check_workers(workers: int | None) -> None:
    """ClusterError unless ``workers`` is None or 1 to the machine's cores (more would only compete for them)."""
    if workers is None:
        return
    cores = machine_cores()
    if not 1 <= workers <= cores:
        shown = str(workers) if len(str(workers)) <= 20 else str(workers)[:20] + "..."
        raise ClusterError(f"--workers: must be 1 to {cores} (this machine's cores), got {shown}")


def check_scheduler(address: str | None) -> None:
    """ClusterError unless ``address`` is None or looks like ``[tcp://]host:port`` (before any connection)."""
    if address is None:
        return
    shown = address if len(address) <= 40 else address[:40] + "..."
    if not _ADDRESS.fullmatch(address):
        raise ClusterError(f"--scheduler {shown!r}: not an address; give [tcp://]HOST:PORT, e.g. tcp://head:8786")
    if not 1 <= int(address.rsplit(":", 1)[1]) <= 65535:
        raise ClusterError(f"--scheduler {shown!r}: the port must be 1 to 65535")


def probe_scheduler(address: str, timeout_s: float | None = None) -> None:
    """ClusterError unless a ``tcp://`` (or bare ``host:port``) address answers as a Dask scheduler within
    ``timeout_s``: a scheduler sends its handshake as soon as it accepts, a frame whose first 8 bytes are its
    length (little-endian). Dask's own connect bounds only the TCP connect: a server that accepts and says nothing
    kept it waiting for ever, and an HTTP server's reply read as a length asked for 3 EiB (MemoryError). Other
    protocols (tls, ws, ucx) are left to Dask's timeout."""
    timeout_s = CONNECT_TIMEOUT_S if timeout_s is None else timeout_s
    protocol, _, rest = address.rpartition("://")
    if protocol not in ("", "tcp"):
        return
    host, _, port = rest.rpartition(":")
    deadline = time.monotonic() + timeout_s
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s) as sock:
            head = b""
            while len(head) < 8:
                sock.settimeout(max(deadline - time.monotonic(), 0.001))
                chunk = sock.recv(8 - len(head))
                if not chunk:
                    raise ClusterError(f"--scheduler {address}: closed the connection without a Dask handshake")
                head += chunk
    except TimeoutError:
        raise ClusterError(
            f"--scheduler {address}: no Dask handshake within {timeout_s:g} s (accepted, then silent: "
            "not a Dask scheduler, or a stuck one)"
        ) from None
    except OSError as exc:
        raise ClusterError(f"--scheduler {address}: cannot connect ({exc.strerror or exc})") from None
    if int.from_bytes(head, "little") > HANDSHAKE_MAX_BYTES:
        raise ClusterError(f"--scheduler {address}: answers, but not as a Dask scheduler (e.g. an HTTP server)")


@contextlib.contextmanager
def open_client(workers: int | None = None, scheduler: str | None = None) -> Iterator[Any]:
    """A Client: of a new LocalCluster (``workers`` processes, one thread each), or of the scheduler at an address."""
    from distributed import Client, LocalCluster

    if scheduler is not None:
        probe_scheduler(scheduler)
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError) as exc:
            why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise ClusterError(f"--scheduler {scheduler}: cannot connect ({why})") from None
        try:
            _check_workers(client, scheduler)
            yield client
        finally:
            client.close()
        return
    check_workers(workers)
    n = workers or machine_cores()
    before = set(multiprocessing.active_children())
    try:
        cluster = LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            dashboard_address=":0",  # its HTTP server on a free port (never a clash on 8787)
            silence_logs=logging.ERROR,
            death_timeout=CLUSTER_START_TIMEOUT_S,  # each worker's start, bounded by its nanny
        )
    except Exception as exc:  # a worker's start timed out; Dask then raises TimeoutError, or AssertionError while
        # killing a worker still starting (distributed 2026.8: nanny.py's kill asserts on Status.starting)
        for stuck in set(multiprocessing.active_children()) - before:  # Dask's failed kill may leave one running
            stuck.kill()
            stuck.join(5.0)
        why = next((line for line in str(exc).splitlines() if line.strip()), "")[:160]
        raise ClusterError(
            f"the local cluster's {n} worker(s) did not start within {CLUSTER_START_TIMEOUT_S:g} s "
            f"(sweep.engine.CLUSTER_START_TIMEOUT_S; Dask: {type(exc).__name__}{': ' + why if why else ''})"
        ) from None
    with cluster, Client(cluster) as client:
        yield client


def _check_workers(client: Any, scheduler: str) -> None:
    """At least one worker, each running this driver's gantry-twin and Python."""
    try:
        client.wait_for_workers(1, timeout=WORKERS_TIMEOUT_S)
    except TimeoutError:
        raise ClusterError(f"--scheduler {scheduler}: no worker joined within {WORKERS_TIMEOUT_S:g} s") from None
    mine = worker_versions()
    for address, theirs in client.run(worker_versions, on_error="return").items():
        if isinstance(theirs, BaseException):
            raise ClusterError(f"worker {address} cannot run gantry-twin ({type(theirs).__name__}: {theirs})")
        if theirs["gantry_twin"] != mine["gantry_twin"]:
            raise ClusterError(
                f"worker {address} runs gantry-twin {theirs['gantry_twin']}, this driver {mine['gantry_twin']}; "
                "install the same version on every worker"
            )


def prepare_workers(client: Any, resolved: Sequence[dict[str, Any]], source: str) -> None:
    """Warm up every current worker for these scenarios (one per controller), before the runs."""
    distinct = {json.dumps([r["controller"], r["monitor"]["enable"]], default=str): r for r in resolved}
    workers = list(client.scheduler_info()["workers"])
    futures = [
        client.submit(_warm_up_all, list(distinct.values()), source, workers=[w], allow_other_workers=False, pure=False)
        for w in workers
    ]
    from distributed import wait

    try:
        with _compile_notice(list(distinct.values()), source):  # a line, and seconds on a terminal, if they compile
            wait(futures, timeout=WARM_UP_TIMEOUT_S)
    except TimeoutError:
        client.cancel(futures)
        raise ClusterError(
            f"the workers did not compile or load the loop within {WARM_UP_TIMEOUT_S:g} s "
            f"(sweep.engine.WARM_UP_TIMEOUT_S): a worker stuck, or a process holding {cache_dir()}/{COMPILE_LOCK}"
        ) from None
    client.gather(futures, errors="skip")  # a worker that died warms up in its first task


def _compile_notice(distinct: Sequence[dict[str, Any]], source: str) -> contextlib.AbstractContextManager[Any]:
    """The driver's line while the workers warm up, when their loops compile first (the numba cache of this
    install: a local cluster's workers share it), counting seconds on a terminal; nothing otherwise."""
    from gantry_twin.loop.compiling import batch_compile_notice

    controllers = []
    for r in distinct:
        with contextlib.suppress(Exception):  # a scenario that does not build fails in its task, with its message
            controllers.append(build(validate_data(r, source), source).controller)
    return batch_compile_notice(controllers, "gantry-twin")


def run_tasks(
    client: Any,
    function: Callable[..., Any],
    arguments: Iterable[tuple[Any, ...]],
    progress: bool = False,
    desc: str = "sweep",
    total: int | None = None,
    initial: int = 0,
    ahead: int = IN_FLIGHT_PER_THREAD,
) -> Iterator[tuple[int, Any, Exception | None]]:
    """Submit ``function(*args)`` for each args; yield (index, result, None) or (index, None, error) as they finish.

    Impure submits: every call is its own task. At most ``ahead`` tasks
    per worker thread are submitted at a time (a big sweep's scenarios are
    not all held by the scheduler, and an interrupt has little to cancel);
    ``arguments`` may be a lazy iterable, drawn from only when a task is
    submitted (a tuner asks its next design when a worker is free); pending
    tasks are cancelled when the caller stops early. The progress bar
    counts points done of ``total`` (``initial`` done before), with rate and ETA.
    """
    from distributed import as_completed
    from tqdm import tqdm

    futures: dict[Any, int] = {}
    queue = iter(enumerate(arguments))
    finished = as_completed()

    def submit_next() -> None:
        item = next(queue, None)
        if item is not None:
            future = client.submit(function, *item[1], pure=False)
            futures[future] = item[0]
            finished.add(future)

    threads = sum(client.nthreads().values()) or 1
    for _ in range(ahead * threads):
        submit_next()
    bar = tqdm(
        total=total if total is not None else len(arguments),  # type: ignore[arg-type]
        initial=initial,
        unit="point",
        desc=desc,
        disable=not progress,
        leave=False,
        smoothing=0.1,
    )
    try:
        for future in finished:
            index = futures.pop(future)
            try:
                result, error = future.result(), None
            except Exception as exc:  # the task raised, or its worker died too often (KilledWorker)
                result, error = None, exc
            future.release()
            submit_next()
            bar.update()
            yield index, result, error
    finally:
        bar.close()
        client.cancel(list(futures))


def run_batch(
    function: Callable[..., Any],
    arguments: Sequence[tuple[Any, ...]],
    resolved: Sequence[dict[str, Any]],
    source: str,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = False,
    desc: str = "batch",
    total: int | None = None,
    initial: int = 0,
    on_ready: Callable[[], None] | None = None,
) -> Iterator[tuple[int, Any, Exception | None]]:
    """The one batch runner: ``function(*args)`` for each args on a Dask cluster, as each finishes.

    A local cluster of ``workers`` processes, or the running one at
    ``scheduler``; every worker first compiles or loads the loops of the
    ``resolved`` scenarios (:func:`prepare_workers`), then ``on_ready`` is
    called and :func:`run_tasks` yields (index, result, error). A sweep, the
    paper's report matrix run through it (a calibration's batches: :func:`open_batches`).
    """
    with open_client(workers, scheduler) as client:
        if arguments:
            prepare_workers(client, resolved, source)
        if on_ready is not None:
            on_ready()
        yield from run_tasks(client, function, arguments, progress, desc, total, initial)


@contextlib.contextmanager
def open_stream(
    resolved: Sequence[dict[str, Any]], source: str, workers: int | None = None, scheduler: str | None = None
) -> Iterator[Callable[..., Iterator[tuple[int, Any, Exception | None]]]]:
    """:func:`run_tasks` on one cluster for a caller whose next task depends on the last results (a tuner's
    trials): the cluster is opened and every worker warmed up for the ``resolved`` scenarios once; the yielded
    ``stream(function, arguments, ahead=1, ...)`` is :func:`run_tasks` on it, ``arguments`` drawn lazily."""
    with open_client(workers, scheduler) as client:
        prepare_workers(client, resolved, source)

        def stream(
            function: Callable[..., Any], arguments: Iterable[tuple[Any, ...]], ahead: int = 1, **options: Any
        ) -> Iterator[tuple[int, Any, Exception | None]]:
            return run_tasks(client, function, arguments, ahead=ahead, **options)

        yield stream


@contextlib.contextmanager
def open_batches(
    resolved: Sequence[dict[str, Any]], source: str, workers: int | None = None, scheduler: str | None = None
) -> Iterator[Callable[[Callable[..., Any], Sequence[tuple[Any, ...]]], list[Any]]]:
    """:func:`run_all` for a caller that runs one batch after another on one cluster (a calibration: each of its
    optimiser's evaluations is a batch of runs, decided by the results of the last).

    The cluster is opened and every worker warmed up for the ``resolved``
    scenarios once; the yielded ``run(function, arguments)`` returns the
    results in the order of ``arguments`` and raises the first task's error.
    """
    with open_client(workers, scheduler) as client:
        prepare_workers(client, resolved, source)

        def run(function: Callable[..., Any], arguments: Sequence[tuple[Any, ...]]) -> list[Any]:
            return in_order(run_tasks(client, function, arguments), len(arguments))

        yield run


def run_all(
    function: Callable[..., Any],
    arguments: Sequence[tuple[Any, ...]],
    resolved: Sequence[dict[str, Any]],
    source: str,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = False,
    desc: str = "batch",
) -> list[Any]:
    """:func:`run_batch` to the end: the results in the order of ``arguments``; the first task's error is raised."""
    batch = run_batch(function, arguments, resolved, source, workers, scheduler, progress, desc)
    return in_order(batch, len(arguments))


def in_order(finished: Iterator[tuple[int, Any, Exception | None]], count: int) -> list[Any]:
    """The results of ``count`` tasks yielded as they finish, in task order; the first task error is raised."""
    done: dict[int, Any] = {}
    for index, result, error in finished:
        if error is not None:
            raise error
        done[index] = result
    return [done[i] for i in range(count)]
