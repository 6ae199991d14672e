"""Which nodes of a machine's OPC UA server ``monitor --opcua`` reads: the node map (docs/live-link.md).

A node map file (``--nodes FILE``, YAML)::

    sample_period_s: 0.0002          # the machine's control period; the estimator runs at it
    blocks: "nsu=urn:gantry-twin:opcua;s=GantryTwin.SampleBlock"     # optional: sample blocks
    run_state: "nsu=urn:gantry-twin:opcua;s=GantryTwin.RunState"     # optional: idle/running/finished/failed
    signals:                         # scalar subscriptions, read when there are no blocks
      x_m:   {node: "ns=3;s=Axis.X.ActPos", unit: m}
      y_m:   {node: "ns=3;s=Axis.Y.ActPos", unit: m}
      u_x_v: {node: "ns=3;s=Drive.X.Command", unit: V}
      u_y_v: {node: "ns=3;s=Drive.Y.Command", unit: V}

Node ids are OPC UA's text form: ``ns=<index>;s=<name>`` (or ``i=``, ``g=``, ``b=``), or ``nsu=<namespace URI>;...``,
which is resolved on the server (an index can change between a server's restarts, a URI does not). Where a
node has an ``EngineeringUnits`` property (blocks: ``BlockUnits``), it must say the unit declared here.
:func:`default_node_map` is ``gantry-twin serve``'s own address space, so that twin-to-twin needs no file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from gantry_twin.inputs import read_input_file
from gantry_twin.link.address_space import NAMESPACE, TWIN, a_path

#: The scalar signals the shadow monitor needs, and their units.
REQUIRED_SIGNALS: dict[str, str] = {"x_m": "m", "y_m": "m", "u_x_v": "V", "u_y_v": "V"}
#: Node map keys.
KEYS = ("sample_period_s", "blocks", "run_state", "signals")


class NodeMapError(ValueError):
    """A node map that cannot be used; the message is one line naming the file and the field."""


@dataclass(frozen=True)
class Signal:
    node: str
    unit: str


@dataclass(frozen=True)
class NodeMap:
    """The nodes to read: sample blocks (``blocks``) or scalar ``signals``; the run state; the sample period (s;
    None: read from the server's ``GantryTwin.SamplePeriod``)."""

    sample_period_s: float | None
    blocks: str | None
    run_state: str | None
    signals: dict[str, Signal] = field(default_factory=dict)
    source: str = "<default: gantry-twin serve's address space>"

    @property
    def mode(self) -> str:
        return "blocks" if self.blocks else "scalars"


def twin_node(path: str) -> str:
    return f"nsu={NAMESPACE};s={path}"


def default_node_map() -> NodeMap:
    """``gantry-twin serve``'s own nodes: its sample blocks and run state (the scalars for a scalar subscriber)."""
    signals = {
        "x_m": Signal(twin_node(f"{a_path('X')}.PosDirect.ActPos"), "m"),
        "y_m": Signal(twin_node(f"{a_path('Y')}.PosDirect.ActPos"), "m"),
    }
    return NodeMap(None, twin_node(f"{TWIN}.SampleBlock"), twin_node(f"{TWIN}.RunState"), signals)


def read_node_map(path: Path) -> NodeMap:
    """A node map file (module docstring); NodeMapError naming the file and the field on the first problem."""
    where = f"--nodes {path}"
    try:
        data = yaml.safe_load(read_input_file(path, "a node map YAML file"))
    except (OSError, ValueError, yaml.YAMLError) as exc:
        raise NodeMapError(f"{where}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
    if not isinstance(data, dict):
        raise NodeMapError(f"{where}: expected a mapping with {', '.join(KEYS)}")
    unknown = sorted(set(data) - set(KEYS))
    if unknown:
        raise NodeMapError(f"{where}: unknown key {unknown[0]!r}; the keys are {', '.join(KEYS)}")
    period = data.get("sample_period_s")
    if (
        not isinstance(period, int | float)
        or isinstance(period, bool)
        or not (0 < period <= 1 and math.isfinite(period))
    ):
        raise NodeMapError(f"{where}: sample_period_s: a number of seconds in (0, 1], got {period!r}")
    blocks, run_state = (_node_id(where, key, data.get(key)) for key in ("blocks", "run_state"))
    signals: dict[str, Signal] = {}
    raw = data.get("signals") or {}
    if not isinstance(raw, dict):
        raise NodeMapError(f"{where}: signals: a mapping of {', '.join(REQUIRED_SIGNALS)} to {{node, unit}}")
    for name, entry in raw.items():
        if name not in REQUIRED_SIGNALS:
            raise NodeMapError(f"{where}: signals.{name}: unknown; the signals are {', '.join(REQUIRED_SIGNALS)}")
        if not isinstance(entry, dict) or set(entry) != {"node", "unit"}:
            raise NodeMapError(f"{where}: signals.{name}: expected {{node: ID, unit: {REQUIRED_SIGNALS[name]}}}")
        if entry["unit"] != REQUIRED_SIGNALS[name]:
            raise NodeMapError(
                f"{where}: signals.{name}.unit: {entry['unit']!r}; the twin reads {name} in {REQUIRED_SIGNALS[name]}"
            )
        signals[name] = Signal(str(_node_id(where, f"signals.{name}.node", entry["node"])), entry["unit"])
    if blocks is None and set(signals) != set(REQUIRED_SIGNALS):
        missing = sorted(set(REQUIRED_SIGNALS) - set(signals))
        raise NodeMapError(f"{where}: no blocks, and signals lacks {', '.join(missing)}")
    return NodeMap(float(period), blocks, run_state, signals, str(path))


def _node_id(where: str, key: str, value: object) -> str | None:
    if value is None:
        return None
    text = str(value)
    if not isinstance(value, str) or not any(part.startswith(("i=", "s=", "g=", "b=")) for part in text.split(";")):
        raise NodeMapError(f"{where}: {key}: an OPC UA node id like 'ns=2;s=Name' or 'nsu=URI;i=5', got {value!r}")
    return text
