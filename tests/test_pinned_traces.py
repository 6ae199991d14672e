"""Behaviour pinned across refactors: every shipped scenario x every built-in controller, 2 s, both backends.

Each shipped scenario runs on its default machine, the rig plant (models/rig.xml); the ideal plant
(``plant.model=paper``) is pinned too, DIARC on every scenario and every controller on the plain
circle (keys ``scenario/controller@paper``).

The digests hold on any x86-64 machine: what the loop reads is computed with the C library's sin,
cos and atan2 (``gantry_twin.numerics.libm``, tests/test_libm.py), not numpy's SIMD loops, whose last bits
depend on the CPU.

The digests in ``tests/data/trace_digests.json``: a run that changes any bit of any trace array
changes its digest. Regenerate them only for an intended change of behaviour, and say so in the
commit:

    python tests/test_pinned_traces.py --record
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from gantry_twin import simulate
from gantry_twin.scenario import build, load_scenario, shipped_scenarios

DIGESTS = Path(__file__).parent / "data" / "trace_digests.json"
CONTROLLERS = ("diarc", "darc", "drc", "pd")
DURATION_S = 2.0
#: Windows inside the 2 s run; neither changes the trace.
OVERRIDES = [f"duration_s={DURATION_S}", "window_s=[0.5, 2.0]", "estimates_window_s=[1.0, 2.0]", "monitor.enable=false"]
FIELDS = ("q_m", "q_meas_m", "q_d_m", "e_m", "eps_n_m", "eps_c_m", "u_v", "disturbance_v", "true_theta")


def _digest(values: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(values, dtype=np.float64).tobytes()).hexdigest()[:24]


#: The plants pinned: the scenario's default machine (the rig plant) and the ideal plant.
PLANTS = {"": (), "@paper": ("plant.model=paper",)}


def trace_digests(scenario: str, controller: str, backend: str, plant: str = "") -> dict[str, str]:
    """Per-array sha256 prefixes of a 2 s run's trace; ``plant`` a key of :data:`PLANTS`."""
    path = next(p for p in shipped_scenarios() if p.stem == scenario)
    built = build(load_scenario(path, [*OVERRIDES, *PLANTS[plant]], controller), str(path))
    trace = simulate(
        built.plant,
        built.path,
        built.timing,
        built.controller,
        DURATION_S,
        sensing=built.sensing,
        disturbance=built.disturbance,
        changes=built.changes,
        backend=backend,
    )
    out = {name: _digest(getattr(trace, name)) for name in FIELDS}
    out.update({f"state.{key}": _digest(value) for key, value in sorted(trace.controller_state.items())})
    return out


CASES = [(p.stem, c) for p in shipped_scenarios() for c in CONTROLLERS]
#: The ideal plant's cases: every controller on the plain circle and DIARC on every scenario.
PAPER_CASES = sorted({("no_load_circle", c) for c in CONTROLLERS} | {(p.stem, "diarc") for p in shipped_scenarios()})
#: The compiled cases the quick run (-m "not slow") keeps: every controller on the plain circle, and DIARC
#: on each scenario that exercises another per-sample concern of the loop (disturbance input, payload
#: change, friction drift, cogging). The others, and the whole reference half, are marked slow.
REPRESENTATIVE = {("no_load_circle", c) for c in CONTROLLERS} | {
    (s, "diarc")
    for s in ("step_disturbance_circle", "payload_pickup_circle", "friction_drift_circle", "cogging_circle")
}


def _recorded() -> dict[str, dict[str, str]]:
    return json.loads(DIGESTS.read_text(encoding="utf-8"))


@pytest.mark.parametrize(
    ("scenario", "controller"),
    [pytest.param(*case, marks=() if case in REPRESENTATIVE else pytest.mark.slow) for case in CASES],
)
def test_compiled_trace_is_pinned(scenario, controller):
    assert trace_digests(scenario, controller, "compiled") == _recorded()[f"{scenario}/{controller}"]


@pytest.mark.parametrize(
    ("scenario", "controller"),
    [pytest.param(*case, marks=() if case in REPRESENTATIVE else pytest.mark.slow) for case in PAPER_CASES],
)
def test_compiled_trace_on_the_ideal_plant_is_pinned(scenario, controller):
    got = trace_digests(scenario, controller, "compiled", "@paper")
    assert got == _recorded()[f"{scenario}/{controller}@paper"]


#: The reference cases the whole suite (CI) runs: every controller on the plain circle (the reference backend
#: runs the Python interpreter, about 50 times the compiled loop's cost). The other 32 only with
#: ``-m exhaustive``, to keep the suite under 10 minutes: the compiled digests of every case stay in the suite,
#: and tests/test_backends.py checks compiled == reference for each per-sample concern those scenarios add
#: (disturbance input, plant changes, drift, cogging, ideal sensing).
REFERENCE_IN_SUITE = {("no_load_circle", c) for c in CONTROLLERS}


@pytest.mark.slow
@pytest.mark.parametrize(
    ("scenario", "controller"),
    [pytest.param(*case, marks=() if case in REFERENCE_IN_SUITE else pytest.mark.exhaustive) for case in CASES],
)
def test_reference_trace_is_pinned(scenario, controller):
    assert trace_digests(scenario, controller, "reference") == _recorded()[f"{scenario}/{controller}"]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("scenario", "controller"),
    [("no_load_circle", "diarc"), pytest.param("cogging_circle", "diarc", marks=pytest.mark.exhaustive)],
)
def test_reference_trace_on_the_ideal_plant_is_pinned(scenario, controller):
    got = trace_digests(scenario, controller, "reference", "@paper")
    assert got == _recorded()[f"{scenario}/{controller}@paper"]


def test_every_shipped_case_is_pinned():
    expected = [f"{s}/{c}" for s, c in CASES] + [f"{s}/{c}@paper" for s, c in PAPER_CASES]
    assert sorted(_recorded()) == sorted(expected)
    assert REPRESENTATIVE <= set(CASES)


if __name__ == "__main__" and "--record" in sys.argv:
    DIGESTS.parent.mkdir(exist_ok=True)
    table = {f"{s}/{c}{k}": trace_digests(s, c, "compiled", k) for k, cases in (("", CASES), ("@paper", PAPER_CASES))
             for s, c in cases}  # fmt: skip
    DIGESTS.write_text(json.dumps(table, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    print(f"wrote {len(table)} cases to {DIGESTS}")
