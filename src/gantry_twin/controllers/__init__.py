"""Controllers and their plug-in registry (see :mod:`.base` for the protocol)."""

from gantry_twin.controllers.arc import DARC, DIARC, DRC
from gantry_twin.controllers.base import (
    Controller,
    Measurement,
    PluginError,
    ReferenceSample,
    RunContext,
    available,
    create,
    register,
    unregister,
)
from gantry_twin.controllers.estimator import RECOMMENDED_ESTIMATOR, EstimatorSettings
from gantry_twin.controllers.law import ArcGains
from gantry_twin.controllers.pd import PD

register("drc", DRC)
register("darc", DARC)
register("diarc", DIARC)
register("pd", PD)

__all__ = [
    "DARC",
    "DIARC",
    "DRC",
    "PD",
    "RECOMMENDED_ESTIMATOR",
    "ArcGains",
    "Controller",
    "EstimatorSettings",
    "Measurement",
    "PluginError",
    "ReferenceSample",
    "RunContext",
    "available",
    "create",
    "register",
    "unregister",
]
