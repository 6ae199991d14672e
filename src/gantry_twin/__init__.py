"""gantry-twin: a MuJoCo digital twin of a biaxial linear-motor gantry (Hu, Yao, Wang 2010)."""

from gantry_twin.contours import TimingLaw, circle, paper_ellipse
from gantry_twin.controllers import available, create, register
from gantry_twin.plant import Payload, Plant, true_parameters
from gantry_twin.sensing import SensingConfig
from gantry_twin.simulate import simulate
from gantry_twin.trace import Trace

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
    "simulate",
    "true_parameters",
]
