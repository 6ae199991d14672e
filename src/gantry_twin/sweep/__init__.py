"""Sweeps and Monte Carlo studies on Dask distributed: ``gantry-twin sweep FILE`` (docs/sweeps.md).

The modules, in the order data flows:

* :mod:`.spec`: the sweep file (which scenario, what to set, the axes, random
  fields, repeats, the metrics to keep), validated like a scenario file.
* :mod:`.sampling`: grid values, ranges and seeded random draws (uniform,
  normal, log-uniform; independent or Latin hypercube).
* :mod:`.points`: every point loaded and checked as ``gantry-twin run`` would
  (before any run); the function a worker runs for one point.
* :mod:`.engine`: Dask: a LocalCluster or a running cluster, per-worker
  warm-up of the compiled loop, impure submits, results as they finish.
* :mod:`.table`: ``results.parquet``, rewritten atomically after each point.
* :mod:`.plots`: the figures and ``summary.md``.
* :mod:`.driver`: :func:`run_sweep`, the whole of ``gantry-twin sweep``.
"""

from gantry_twin.sweep.driver import SweepOutcome, existing_results, run_sweep, set_aside
from gantry_twin.sweep.engine import ClusterError
from gantry_twin.sweep.points import Plan, Point, plan_sweep
from gantry_twin.sweep.spec import SweepSpec, load_sweep, sweep_file, sweeps_dir

__all__ = [
    "ClusterError",
    "Plan",
    "Point",
    "SweepOutcome",
    "SweepSpec",
    "existing_results",
    "load_sweep",
    "plan_sweep",
    "run_sweep",
    "set_aside",
    "sweep_file",
    "sweeps_dir",
]
