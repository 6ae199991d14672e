"""The paper's parameter vector theta (eq. 3, property P3) in volt units: its names, units and nominal values.

theta = (M1, M2, B1, B2, Af1, Af2, dN1, dN2): per axis (X then Y) the moving
mass, viscous friction, Coulomb friction and constant input offset, each
divided by the motor constant kf (docs/equations.md, "The plant").
"""

from __future__ import annotations

from typing import Literal, get_args

#: An axis by name; AXES: the names in the package's order (index 0 = X, 1 = Y).
Axis = Literal["x", "y"]
AXES: tuple[str, str] = get_args(Axis)
#: Names of the eight entries of theta (paper section 2, property P3).
THETA_NAMES: tuple[str, ...] = ("M1", "M2", "B1", "B2", "Af1", "Af2", "dN1", "dN2")
#: Units of the entries of theta, in THETA_NAMES' order (paper section 2: volts per unit of the
#: axis' acceleration, velocity, friction shape and constant).
THETA_UNITS: tuple[str, ...] = ("V/(m/s^2)", "V/(m/s^2)", "V/(m/s)", "V/(m/s)", "V", "V", "V", "V")
#: The paper's nominal theta (section 5, Table 3's theta_iN of Set 1): what least-squares identification
#: returned on the rig without load; dN nominally 0.
NOMINAL_THETA: tuple[float, ...] = (0.12, 0.5, 0.5, 0.7, 0.1, 0.15, 0.0, 0.0)


def per_axis(theta: tuple[float, ...], name: str) -> tuple[float, float]:
    """The (X, Y) pair of one kind of parameter of ``theta``: ``per_axis(NOMINAL_THETA, "M")`` = (0.12, 0.5)."""
    return (theta[THETA_NAMES.index(f"{name}1")], theta[THETA_NAMES.index(f"{name}2")])
