"""The example compiled plug-in (examples/gantry-example-pd), installed as a user would install it.

pip builds and installs the package into a temporary directory (its build
backend, setuptools, comes from PyPI in pip's isolated build); a fresh Python
process finds the controller through the entry-point group, runs it on both
backends and reports what it saw. A second process with the same numba cache
must load the compiled loop rather than compile it again.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from gantry_twin.loop.simulate import compiled_available

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "examples" / "gantry-example-pd"

RUN = """
import json, sys
import numpy as np
from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import available, create
from gantry_twin.controllers.base import compiled_step_of
from gantry_twin.loop.sample import chunk_kernel

traces = {b: simulate(Plant(), circle(), TimingLaw(2.0), create("example_pd"), 0.3, backend=b)
          for b in ("compiled", "reference")}
a, b = traces["compiled"], traces["reference"]
fields = ("q_m", "q_meas_m", "e_m", "eps_n_m", "eps_c_m", "u_v")
kernel = chunk_kernel(compiled_step_of(create("example_pd")))
print(json.dumps({
    "available": "example_pd" in available(),
    "module": type(create("example_pd")).__module__,
    "same": {f: bool(np.array_equal(getattr(a, f), getattr(b, f))) for f in fields},
    "state_keys": sorted(a.controller_state),
    "same_state": bool(np.array_equal(a.controller_state["peak_error_m"], b.controller_state["peak_error_m"])),
    "peak_moves": float(np.ptp(a.controller_state["peak_error_m"][:, 1])),
    "cache_hits": sum(kernel.stats.cache_hits.values()),
    "cache_misses": sum(kernel.stats.cache_misses.values()),
}))
"""


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """The example package installed by pip into a temporary directory (built from a copy: setuptools
    leaves build/ and *.egg-info in the tree it builds)."""
    target = tmp_path_factory.mktemp("site")
    source = shutil.copytree(EXAMPLE, tmp_path_factory.mktemp("example") / EXAMPLE.name)
    pip = [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--target", str(target), str(source)]
    subprocess.run(pip, check=True, capture_output=True)
    return target


def _run(site: Path, cache: Path) -> dict:
    src = str(ROOT / "src")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(site), src]), NUMBA_CACHE_DIR=str(cache))
    out = subprocess.run([sys.executable, "-c", RUN], env=env, capture_output=True, text=True, check=True, cwd=site)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow
@pytest.mark.skipif(not compiled_available(), reason="no compiled backend on this machine")
def test_installed_example_runs_compiled_bit_identical_and_loads_from_the_cache(installed, tmp_path):
    first = _run(installed, tmp_path / "numba")
    assert first["available"] and first["module"] == "gantry_example_pd"
    assert all(first["same"].values()), first["same"]
    assert first["state_keys"] == ["peak_error_m"] and first["same_state"]
    assert first["peak_moves"] > 0.0  # the logged state changes during the run
    assert first["cache_misses"] == 1 and first["cache_hits"] == 0  # compiled here
    second = _run(installed, tmp_path / "numba")
    assert second["cache_hits"] == 1 and second["cache_misses"] == 0  # loaded, not compiled again
