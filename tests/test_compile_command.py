"""gantry-twin compile: the loops compiled ahead of a first run, so that the run compiles nothing."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from gantry_twin.loop.compiling import EXPECTED_PD_COMPILE_S, compile_message
from gantry_twin.loop.simulate import compiled_available

SRC = Path(__file__).resolve().parents[1] / "src"
CLI = "import sys; from gantry_twin.cli import main; sys.exit(main(sys.argv[1:]))"
#: numba's compiles in this process, by kernel name, as they start (none when every kernel came from the cache).
COUNT = """
from numba.core import event
compiled = []
class Compiles(event.Listener):
    def on_start(self, ev):
        compiled.append(ev.data["dispatcher"].py_func.__qualname__)
    def on_end(self, ev):
        pass
event.register("numba:compile", Compiles())
"""
#: The CLI in a new process that also writes the kernels numba compiled during it to the file argv[1].
CLI_AND_COUNT = (
    COUNT
    + """
import atexit, json, sys
from gantry_twin.cli import main
path = sys.argv.pop(1)
atexit.register(lambda: open(path, "w").write(json.dumps(compiled)))
sys.exit(main(sys.argv[1:]))
"""
)
#: A pd run in a new process that prints the kernels numba compiled during it (none when all came from the cache).
RUN_AND_COUNT = (
    COUNT
    + """
import contextlib, io, sys
from gantry_twin.cli import main
with contextlib.redirect_stdout(io.StringIO()):
    code = main(["run", "--controller", "pd", "--set", "duration_s=4", "--out", sys.argv[1], "--no-plots"])
print(code, compiled)
"""
)


def _python(cache: Path, code: str, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(SRC), "NUMBA_CACHE_DIR": str(cache)}
    return subprocess.run([sys.executable, "-c", code, *args], env=env, capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_after_compile_a_run_compiles_nothing(tmp_path):
    if not compiled_available():
        pytest.skip("no compiled backend on this machine")
    cache = tmp_path / "cache"
    counted = tmp_path / "compiled.json"
    first = _python(cache, CLI_AND_COUNT, str(counted), "compile", "--controller", "pd")
    assert first.returncode == 0, first.stderr
    # The counter sees a cold compile: the loop's kernel among what `compile` compiled on the empty cache. (This
    # replaces a second cold compile, a run on another empty cache, that showed the same: ~7 s of CPU.)
    assert any(name.startswith("run_chunk") for name in json.loads(counted.read_text()))
    assert compile_message("gantry-twin (pd)", EXPECTED_PD_COMPILE_S) in first.stderr
    assert first.stdout.startswith("compiled: pd ") and str(cache) in first.stdout
    again = _python(cache, CLI, "compile", "--controller", "pd")
    assert again.returncode == 0 and again.stdout == "pd: already compiled for this install\n" and not again.stderr
    run = _python(cache, RUN_AND_COUNT, str(tmp_path / "run"))
    assert run.stdout.split() == ["0", "[]"], run.stdout + run.stderr  # the run's loop and its summary's kernels
