"""Helpers shared by the test modules: paper scenarios, the reference machine's truth, recordings read back.

Imported normally (``from .helpers import run``); fixtures stay in conftest.py.
"""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

import numpy as np

from gantry_twin import Payload, Plant, SensingConfig, TimingLaw, circle, paper_ellipse, simulate
from gantry_twin.controllers import create

CIRCLE_RATE = 2.0  # rad/s: 0.4 m/s on a 0.2 m radius (paper 5.1)
ELLIPSE_RATE = 3.0  # rad/s (paper 5.2)

# ---------------------------------------------------------------------------
# The reference machine (docs/equations.md, the plant), typed here once as the tests' known truth (SI units,
# index 0 = X, 1 = Y). The paper's theta is each of them divided by the motor gain.

GEAR_N_PER_V = 69.0
MASS_NO_LOAD_KG = np.array([8.28, 34.5])
DAMPING_N_S_PER_M = np.array([34.5, 48.3])
FRICTION_N = np.array([6.9, 10.35])
#: The ARC laws' parameter bounds theta_min, theta_max (paper eq. 7).
THETA_MIN = np.array([0.05, 0.45, 0.35, 0.5, 0.05, 0.08, -0.5, -1.0])
THETA_MAX = np.array([0.20, 0.60, 0.55, 0.8, 0.15, 0.25, 0.5, 1.0])
#: The DS1103's DAC range, volts (docs/equations.md, the plant).
DAC_LIMIT_V = 10.0
#: The travel: 510 mm per axis about its centre (docs/equations.md, the plant), so each end is this far out, m.
TRAVEL_END_M = 0.255
for _constant in (MASS_NO_LOAD_KG, DAMPING_N_S_PER_M, FRICTION_N, THETA_MIN, THETA_MAX):
    _constant.flags.writeable = False  # shared by every test: no test may change them


#: float32's relative rounding, 2**-24 (half an ulp). trace.parquet stores every column but time and the
#: positions as float32 (gantry_twin.outputs.tracefile.FLOAT64_COLUMNS): a figure computed from those columns is
#: within this (twice it, leaving room for the float64 arithmetic on top) of the figure computed in memory.
FLOAT32_REL = 2.0**-24


def trace_column(table, name: str) -> np.ndarray:
    """A trace.parquet column as float64 (a float32 column widened, so that arithmetic on it runs in float64:
    ``float32 array * 1e6`` stays float32 in NumPy 2)."""
    return table.column(name).to_numpy().astype(np.float64)


def spec_theta(payload_kg: float = 0.0) -> np.ndarray:
    """The paper's theta [M1, M2, B1, B2, Af1, Af2, dN1, dN2] (volt units) of the reference machine carrying payload_kg.

    The payload rides on the X carriage, which the Y carriage carries: it adds to both moving masses.
    """
    si = np.concatenate([MASS_NO_LOAD_KG + payload_kg, DAMPING_N_S_PER_M, FRICTION_N])
    return np.concatenate([si / GEAR_N_PER_V, np.zeros(2)])


def pushed_from_rest_m(
    t_s: np.ndarray, axis: int, volts: float, payload_kg: float = 0.0, friction_n: float | None = None
) -> np.ndarray:
    """Displacement (m) of a carriage starting at rest under a constant command, before it meets anything.

    The reference machine: m x'' = kf u - B x' - Fc sign(x'), with |kf u| > Fc, so the
    carriage moves off at once in the direction of u and x' keeps that sign:
    x' = v_inf (1 - exp(-t / tau)), v_inf = (kf |u| - Fc) / B, tau = m / B. friction_n: Fc in place of the
    reference machine's.
    """
    mass = MASS_NO_LOAD_KG[axis] + payload_kg
    damping = DAMPING_N_S_PER_M[axis]
    coulomb = FRICTION_N[axis] if friction_n is None else friction_n
    v_inf = (GEAR_N_PER_V * abs(volts) - coulomb) / damping
    tau = mass / damping
    t = np.asarray(t_s, dtype=float)
    return np.sign(volts) * v_inf * (t - tau * (1.0 - np.exp(-t / tau)))


def deviation_pct(estimate: np.ndarray | float, true: np.ndarray | float) -> np.ndarray | float:
    """How far an estimate is from the truth, percent of the truth: 100 (estimate - true) / true."""
    return 100.0 * (np.asarray(estimate) - np.asarray(true)) / np.asarray(true)


# ---------------------------------------------------------------------------
# Paper scenarios as small helpers (no scenario files needed).


def contour(name: str):
    """(path, timing law, period s) of the paper's circle or ellipse, on_path start."""
    if name == "circle":
        return circle(), TimingLaw(CIRCLE_RATE), 2 * math.pi / CIRCLE_RATE
    return paper_ellipse(), TimingLaw(ELLIPSE_RATE), 2 * math.pi / ELLIPSE_RATE


def step_on_y(value_v: float = 0.6, start_s: float = 1.86, end_s: float = 4.86):
    """The paper's Set 3 disturbance: value_v on the Y input from start_s to end_s."""

    def disturbance(t: np.ndarray) -> np.ndarray:
        d = np.zeros((t.size, 2))
        d[(t >= start_s) & (t < end_s), 1] = value_v
        return d

    return disturbance


def run(
    name: str,
    contour_name: str = "circle",
    duration_s: float = 7.0,
    payload_kg: float = 0.0,
    sensing: SensingConfig | None = None,
    disturbance=None,
    observers=(),
    controller=None,
    **options,
):
    """Simulate one paper-style run of controller ``name`` (or of ``controller``); returns (trace, period s)."""
    path, timing, period = contour(contour_name)
    controller = controller if controller is not None else create(name, **options)
    trace = simulate(
        Plant(Payload(payload_kg)),
        path,
        timing,
        controller,
        duration_s,
        sensing=sensing,
        disturbance=disturbance,
        observers=observers,
    )
    return trace, period


def run_main(argv: list[str], capsys) -> tuple[int, str, str]:  # noqa: ANN001
    """The command line through ``gantry_twin.cli.app``: (exit code, stdout, stderr)."""
    from gantry_twin.cli import app as cli

    code = cli.main(argv)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


# ---------------------------------------------------------------------------
# Rerun recordings read back headless (rerun 0.41).


def read_rrd(path: Path) -> dict[str, dict[str, np.ndarray]]:
    """Temporal data of the first recording in an .rrd: entity -> {"time_ns": (N,), component: (N, k)}."""
    import rerun as rr

    rows: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for chunk in rr.chunk.RrdReader(path).stream().to_chunks():
        if chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        entity = chunk.entity_path.lstrip("/")
        rows[entity]["time_ns"].extend(batch.column("sim_time").cast("int64").to_pylist())
        for field in batch.schema:
            if ":" in field.name:
                rows[entity][field.name].extend(batch.column(field.name).to_pylist())
    out = {}
    for entity, columns in rows.items():
        order = np.argsort(columns["time_ns"], kind="stable")
        out[entity] = {name: [values[i] for i in order] for name, values in columns.items()}
        out[entity]["time_ns"] = np.asarray(out[entity]["time_ns"])
    return out


def scalars(data: dict[str, dict], entity: str) -> np.ndarray:
    """The Scalars component of one entity of :func:`read_rrd`'s result, (N, k)."""
    return np.asarray(data[entity]["Scalars:scalars"], dtype=float)


#: The abstract socket name the tests that run LinuxCNC take turns on: LinuxCNC's shared memory is the machine's,
#: and a test that looks for LinuxCNC's processes (or kills one by name) must see its own only.
LINUXCNC_TESTS_TURN = "\0gantry-twin-linuxcnc-tests"


def linuxcnc_turn(limit_s: float = 900.0):
    """Hold the machine's turn for a test that runs LinuxCNC (the other pytest-xdist workers' wait)."""
    from gantry_twin.cnc.session import turn

    return turn(LINUXCNC_TESTS_TURN, limit_s, "another test that runs LinuxCNC")
