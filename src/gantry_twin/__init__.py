"""gantry-twin: a MuJoCo digital twin of a biaxial linear-motor gantry (Hu, Yao, Wang 2010)."""

import gantry_twin.fmi  # noqa: F401 -- registers the controller "fmu" (a room above the core: docs/fmi.md)
from gantry_twin.controllers import available, create, register
from gantry_twin.loop.simulate import simulate
from gantry_twin.loop.trace import Trace
from gantry_twin.paths.contours import TimingLaw, circle, paper_ellipse
from gantry_twin.plant.model import Payload, Plant, true_parameters
from gantry_twin.plant.sensing import SensingConfig


def __getattr__(name: str) -> object:
    """``__version__`` and :func:`run_scenario`, loaded on first use (they sit above the core's floors)."""
    if name == "__version__":
        from gantry_twin.run import package_version

        return package_version()
    if name in ("run_scenario", "ScenarioRun"):
        from gantry_twin import run

        return getattr(run, name)
    raise AttributeError(f"module 'gantry_twin' has no attribute {name!r}")


__all__ = [
    "Payload",
    "Plant",
    "SensingConfig",
    "TimingLaw",
    "Trace",
    "available",
    "circle",
    "create",
    "paper_ellipse",
    "register",
    "run_scenario",
    "simulate",
    "true_parameters",
]
