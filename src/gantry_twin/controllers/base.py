"""The controller plug-in interface: the :class:`Controller` protocol, its compiled form and the registry.

A controller is anything with ``reset(context)``, ``update(measurement, reference) -> volts`` (every sample;
the loop clips the two commands and holds them over the sample) and ``state_for_logging()`` (same keys and
shapes every sample); it owns all its state, nothing is global. Register it with :func:`register` or the
entry-point group ``gantry_twin.controllers``. It may also offer a compiled step (:class:`CompiledStep` as a
class attribute ``compiled``, plus ``kernel_arguments()``); the loop uses it only if the class offering it
also defines or inherits ``update`` and ``state_for_logging``. :func:`log_values` gives ``state_for_logging``
from the log kernel, so the two cannot disagree.

(docs/plugins.md, "The compiled step")
"""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Any, NamedTuple, Protocol, runtime_checkable

import numpy as np

from gantry_twin.numerics.jit import reference
from gantry_twin.settings import quote, shorten

ENTRY_POINT_GROUP = "gantry_twin.controllers"

#: The DS1103 DAC range (X, Y), volts: a controller's limits until ``reset`` gives it the plant's (RunContext.u_max_v).
U_MAX_V = (10.0, 10.0)

#: Columns of a reference row (:meth:`ReferenceSample.row`, :meth:`gantry_twin.paths.contours.Reference.packed`):
#: q_d (2,) m, q_d' (2,) m/s, q_d'' (2,) m/s^2, alpha rad, alpha' rad/s, alpha'' rad/s^2.
REF_Q, REF_DQ, REF_DDQ, REF_ALPHA, REF_DALPHA, REF_DDALPHA = 0, 2, 4, 6, 7, 8


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
        """From a row of :meth:`gantry_twin.paths.contours.Reference.packed`."""
        return cls(row[0:2], row[2:4], row[4:6], float(row[6]), float(row[7]), float(row[8]))

    def row(self) -> np.ndarray:
        """The packed row (9,) a compiled step reads (columns REF_Q ... REF_DDALPHA)."""
        return np.concatenate([self.q_d, self.dq_d, self.ddq_d, [self.alpha, self.dalpha, self.ddalpha]]).astype(float)


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


#: A compiled controller's log layout: ((name, shape), ...), shape () for one number.
LogLayout = tuple[tuple[str, tuple[int, ...]], ...]


class CompiledStep(NamedTuple):
    """A controller's compiled form (see the module docstring): step and log kernels, log layout."""

    step: Callable[..., Any]
    log: Callable[..., Any] | None = None
    layout: LogLayout = ()

    @property
    def log_size(self) -> int:
        """How many numbers one sample of the log holds."""
        return sum(int(np.prod(shape)) for _, shape in self.layout)


def compiled_step_of(controller: object) -> CompiledStep | None:
    """The controller's :class:`CompiledStep` if the compiled loop may run it, else None."""
    mro = type(controller).__mro__
    owner = next((c for c in mro if isinstance(c.__dict__.get("compiled"), CompiledStep)), None)
    if owner is None or not callable(getattr(controller, "kernel_arguments", None)):
        return None
    for method in ("update", "state_for_logging"):
        defined = next((c for c in mro if method in c.__dict__), None)
        if defined is not None and defined is not owner and issubclass(defined, owner):
            return None  # overridden below the class that offers the compiled step
    return owner.__dict__["compiled"]


def log_values(compiled: CompiledStep, params: tuple, state: tuple) -> dict[str, np.ndarray]:
    """``state_for_logging`` of a compiled controller: its log kernel (uncompiled) split by its layout."""
    if compiled.log is None:
        return {}
    out = np.zeros(compiled.log_size)
    reference(compiled.log)(params, state, out)
    values, at = {}, 0
    for name, shape in compiled.layout:
        size = int(np.prod(shape))
        values[name] = out[at : at + size].reshape(shape or (1,)).copy()
        at += size
    return values


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
    names.update(_entry_point_names(tuple(sys.path)))
    return sorted(names)


@functools.lru_cache(maxsize=8)
def _entry_point_names(path: tuple[str, ...]) -> frozenset[str]:
    """The entry-point controllers' names on this import path: scanning every installed distribution takes
    some 50 ms, once per path (a sweep of 2000 points validates each point's controller name)."""
    return frozenset(ep.name for ep in entry_points(group=ENTRY_POINT_GROUP))


class PluginError(ValueError):
    """A plug-in controller that cannot be imported or made: its module raised (or is missing), or its factory
    raised something other than TypeError / ValueError, or called ``sys.exit()``. One line saying which."""


def _why(exc: BaseException) -> str:
    first = str(exc).splitlines()[0] if str(exc) else ""
    return f"{type(exc).__name__}: {shorten(first, 100)}" if first else type(exc).__name__


def factory_for(name: str) -> ControllerFactory:
    """The factory registered as ``name`` (registry first, then entry points); PluginError if its module raises."""
    if name in _REGISTRY:
        return _REGISTRY[name]
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        if ep.name == name:
            try:
                return ep.load()
            except (Exception, SystemExit) as exc:  # a missing module, one that raises or exits at import
                raise PluginError(f"the plug-in of controller {quote(name)} cannot be imported ({_why(exc)})") from None
    raise KeyError(f"unknown controller {quote(name)}; available: {', '.join(available())}")


def create(name: str, **options: Any) -> Controller:
    """Instantiate the controller registered as ``name`` with keyword options.

    TypeError and ValueError from its factory are the options' fault and pass through; anything else it raises,
    ``sys.exit()`` included (never an exit 0 of the program), is a PluginError."""
    factory = factory_for(name)
    try:
        controller = factory(**options)
    except (TypeError, ValueError):
        raise
    except (Exception, SystemExit) as exc:
        raise PluginError(f"controller {quote(name)} raised {_why(exc)} while being made") from None
    if not isinstance(controller, Controller):
        raise TypeError(f"controller {quote(name)} does not implement reset/update/state_for_logging")
    return controller
