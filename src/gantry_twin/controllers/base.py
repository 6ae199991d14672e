"""The controller plug-in interface.

A controller is anything with three methods (a ``typing.Protocol``; no base
class needed):

* ``reset(context)``: called once before a run with :class:`RunContext`
  (sample period, actuator limits, the true initial state is *not* given).
* ``update(measurement, reference) -> volts``: called every 0.2 ms sample
  with what the DS1103 measured and the desired motion at that sample;
  returns the two motor commands (X, Y) in volts. The loop clips them to the
  actuator range and holds them over the sample (ZOH).
* ``state_for_logging() -> dict[str, ndarray]``: the internal state to record
  after each update (e.g. ``theta_hat``, ``dc_hat``); the same keys and
  shapes every sample. Return ``{}`` for none.

Controllers own all their state; nothing is global. Register a controller
class or factory under a name with :func:`register`, or from another package
through the entry-point group ``gantry_twin.controllers``:

    [project.entry-points."gantry_twin.controllers"]
    my_ctrl = "my_pkg.module:MyController"
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Any, Protocol, runtime_checkable

import numpy as np

ENTRY_POINT_GROUP = "gantry_twin.controllers"


@dataclass(frozen=True)
class Measurement:
    """One sample of the sensors: time s, position m (X, Y), velocity m/s (X, Y)."""

    t_s: float
    q_m: np.ndarray
    dq_m_s: np.ndarray


@dataclass(frozen=True)
class ReferenceSample:
    """The desired motion at one sample (SI units).

    q_d m, dq_d m/s, ddq_d m/s^2 as (X, Y); alpha rad with alpha' rad/s and
    alpha'' rad/s^2 the tangent angle of the contour at q_d.
    """

    q_d: np.ndarray
    dq_d: np.ndarray
    ddq_d: np.ndarray
    alpha: float
    dalpha: float
    ddalpha: float

    @classmethod
    def from_row(cls, row: np.ndarray) -> ReferenceSample:
        """From a row of :meth:`gantry_twin.paths.Reference.packed`."""
        return cls(row[0:2], row[2:4], row[4:6], float(row[6]), float(row[7]), float(row[8]))


@dataclass(frozen=True)
class RunContext:
    """What a controller may know about the run before it starts.

    sample_period_s: Ts (0.2 ms). u_max_v: actuator limits (X, Y), volts.
    initial_measurement: the first sample's measurement.
    """

    sample_period_s: float
    u_max_v: np.ndarray
    initial_measurement: Measurement


@runtime_checkable
class Controller(Protocol):
    """The plug-in protocol every controller implements."""

    def reset(self, context: RunContext) -> None: ...

    def update(self, measurement: Measurement, reference: ReferenceSample) -> np.ndarray: ...

    def state_for_logging(self) -> dict[str, np.ndarray]: ...


ControllerFactory = Callable[..., Controller]
_REGISTRY: dict[str, ControllerFactory] = {}


def register(name: str, factory: ControllerFactory | None = None) -> Any:
    """Register a controller factory under ``name``; usable as a decorator."""

    def add(f: ControllerFactory) -> ControllerFactory:
        _REGISTRY[name] = f
        return f

    return add(factory) if factory is not None else add


def unregister(name: str) -> None:
    """Remove a registered controller (tests use this to clean up)."""
    _REGISTRY.pop(name, None)


def available() -> list[str]:
    """Names of the built-in, registered and entry-point controllers."""
    names = set(_REGISTRY)
    names.update(ep.name for ep in entry_points(group=ENTRY_POINT_GROUP))
    return sorted(names)


def factory_for(name: str) -> ControllerFactory:
    """The factory registered as ``name`` (registry first, then entry points)."""
    if name in _REGISTRY:
        return _REGISTRY[name]
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        if ep.name == name:
            return ep.load()
    raise KeyError(f"unknown controller {name!r}; available: {', '.join(available())}")


def create(name: str, **options: Any) -> Controller:
    """Instantiate the controller registered as ``name`` with keyword options."""
    controller = factory_for(name)(**options)
    if not isinstance(controller, Controller):
        raise TypeError(f"controller {name!r} does not implement reset/update/state_for_logging")
    return controller
