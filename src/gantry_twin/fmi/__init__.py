"""FMI: a user's controller FMU in the 0.2 ms loop (docs/fmi.md); the controller is registered as ``fmu``.

It depends on the core (the plug-in protocol of :mod:`gantry_twin.controllers.base`, the kernels of
:mod:`gantry_twin.numerics.jit`); nothing of the core imports it. The package's ``__init__`` imports this room
so that ``controller: {name: fmu}`` is known wherever gantry_twin is.
"""

from gantry_twin.controllers.base import register
from gantry_twin.fmi.controller import fmu_controller

register("fmu", fmu_controller)

__all__ = ["fmu_controller"]
