"""gantry-twin compile: the loops compiled ahead of a first run, so that the run compiles nothing."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from gantry_twin.loop.compiling import EXPECTED_PD_COMPILE_S, compile_message
from gantry_twin.loop.simulate import compiled_available

SRC = Path(__file__).resolve().parents[1] / "src"
CLI = "import sys; from gantry_twin.cli import main; sys.exit(main(sys.argv[1:]))"
#: A pd run in a new process that prints the kernels numba compiled during it (none when all came from the cache).
RUN_AND_COUNT = """
import contextlib, io, sys
from numba.core import event
compiled = []
class Compiles(event.Listener):
    def on_start(self, ev):
        compiled.append(ev.data["dispatcher"].py_func.__qualname__)
    def on_end(self, ev):
        pass
event.register("numba:compile", Compiles())
from gantry_twin.cli import main
with contextlib.redirect_stdout(io.StringIO()):
    code = main(["run", "--controller", "pd", "--set", "duration_s=4", "--out", sys.argv[1], "--no-plots"])
print(code, compiled)
"""


def _python(cache: Path, code: str, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(SRC), "NUMBA_CACHE_DIR": str(cache)}
    return subprocess.run([sys.executable, "-c", code, *args], env=env, capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_after_compile_a_run_compiles_nothing(tmp_path):
    if not compiled_available():
        pytest.skip("no compiled backend on this machine")
    cache = tmp_path / "cache"
    first = _python(cache, CLI, "compile", "--controller", "pd")
    assert first.returncode == 0, first.stderr
    assert compile_message("gantry-twin (pd)", EXPECTED_PD_COMPILE_S) in first.stderr
    assert first.stdout.startswith("compiled: pd ") and str(cache) in first.stdout
    again = _python(cache, CLI, "compile", "--controller", "pd")
    assert again.returncode == 0 and again.stdout == "pd: already compiled for this install\n" and not again.stderr
    run = _python(cache, RUN_AND_COUNT, str(tmp_path / "run"))
    assert run.stdout.split() == ["0", "[]"], run.stdout + run.stderr  # the run's loop and its summary's kernels
    fresh = _python(tmp_path / "other", RUN_AND_COUNT, str(tmp_path / "run2"))
    assert fresh.stdout.split()[0] == "0" and "run_chunk" in fresh.stdout  # without compile, the run compiles
