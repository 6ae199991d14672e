"""Shared fixtures (plain helpers live in tests/helpers.py)."""

from __future__ import annotations

import functools
import os
import threading

import pytest
from hypothesis import settings
from numba.core.dispatcher import Dispatcher

from .helpers import run

# Tests never time (benchmarks/ do): hypothesis' per-example deadline would fail a property test whose first call
# compiles or loads a numba kernel on a loaded machine (seen at 0.45-0.75 s against its 200 ms default).
settings.register_profile("gantry-twin", deadline=None)
settings.load_profile("gantry-twin")


_compiling = threading.local()


def _compile_under_the_lock(compile_):
    """numba's ``Dispatcher.compile`` (which loads from the disk cache, or compiles on a miss) held under the kernel
    cache's cross-process lock, the one a sweep's Dask workers and ``gantry-twin compile`` take
    (sweep.engine.compile_lock): on an empty cache, of two xdist workers that want the same loop, one compiles it
    and the other waits and then loads what it wrote, instead of both compiling it at once (~15 s of CPU each, and
    numba's cache is not safe under concurrent writers). Only the outermost call of a thread takes the lock (a loop's
    compile compiles the kernels it calls). Tests that need a cold compile use their own NUMBA_CACHE_DIR or install
    path in a new process, which this does not touch; what is compiled or loaded is unchanged.
    """

    @functools.wraps(compile_)
    def compile(self, sig):
        if getattr(_compiling, "depth", 0):
            return compile_(self, sig)
        from gantry_twin.sweep.engine import compile_lock

        _compiling.depth = 1
        try:
            with compile_lock():
                return compile_(self, sig)
        finally:
            _compiling.depth = 0

    return compile


Dispatcher.compile = _compile_under_the_lock(Dispatcher.compile)


@pytest.fixture(scope="session")
def circle_set1_traces():
    """Circle, no load, default sensing, 7 s: DRC, DARC, DIARC (used by several tests)."""
    return {name: run(name)[0] for name in ("drc", "darc", "diarc")}


def pytest_xdist_auto_num_workers(config):
    """`-n auto`: one worker per core, at most 4 (each holds MuJoCo, numba's loops and a model: ~0.3 GB)."""
    return max(1, min(4, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1))


#: The test modules that take longest (``python -m pytest --durations=150`` on the 2-core VM), in that order. xdist
#: hands a worker a whole module (``--dist loadfile``, ``--no-loadscope-reorder``) in collection order; with these
#: first, neither worker is left waiting at the end on the other's long module (the last of them, test_sweep.py,
#: came late in the alphabet). Order only: no test depends on it.
LONGEST_FIRST = (
    "test_linuxcnc.py",  # LinuxCNC runs in real time: mostly waiting, while the other worker computes
    "test_sweep.py",
    "test_calibrate.py",
    "test_health_closed_loop.py",
    "test_hostile_commands.py",
    "test_estimates.py",
    "test_docs.py",
    "test_pinned_traces.py",
    "test_logmonitor.py",
    "test_cli.py",
    "test_compiling.py",
    "test_identify_lugre.py",
    "test_report.py",
    "test_signals.py",
    "test_data_loss.py",
    "test_lugre.py",
)


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # a stable sort: the rest keep their order
