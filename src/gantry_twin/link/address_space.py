"""The address space ``gantry-twin serve`` publishes (docs/live-link.md has it as a table).

Two objects under Objects, in the twin's namespace :data:`NAMESPACE`:

- ``CncInterface``: the browse names and structure of the OPC UA CNC companion specification (OPC 40502):
  ``CncAxisList/X`` and ``/Y`` with ``ActStatus`` and the position variables ``PosDirect`` (the encoder: what a
  machine's control reads) and ``PosIndirect`` (the plant's true position, which only a twin has), each with
  ``ActPos``, ``CmdPos`` and ``RemDist`` in metres (``EngineeringUnits``); ``CncChannelList/Channel1`` with
  ``ActStatus``, ``ActProgramStatus`` and ``ActProgramName``.
- ``GantryTwin``: the twin's own: ``RunState``, ``Scenario``, ``Plant``, ``Controller``, ``SamplePeriod``, the
  wall clock of the pass's t = 0 and the pace (``RunStartedAt``, ``RealtimeFactor``), the
  decimated scalar view (``SampleIndex``, ``Time``, ``ContourError``, ``Command``, ``Theta`` with ``ThetaNames``
  and ``ThetaUnits``, ``Trusted``), every sample in ``SampleBlock`` (:mod:`gantry_twin.link.blocks`, its signals
  in ``BlockSignals`` and ``BlockUnits``), ``SamplesPublished``, and the methods ``Start``, ``Stop``, ``Reset``.
  Health alarms are events (``AlarmConditionType``) that ``GantryTwin`` emits.

Node ids are strings (``ns=<NAMESPACE's index>;s=GantryTwin.SampleBlock``) so that a node map names them
without browsing. Every variable is read-only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from asyncua import Node, Server, ua

from gantry_twin.link.blocks import SIGNALS
from gantry_twin.theta import AXES, THETA_NAMES, THETA_UNITS

#: The twin's namespace URI (a URN: it names, it is never fetched).
NAMESPACE = "urn:gantry-twin:opcua"
#: UNECE codes of the units used (OPC UA Part 8's EUInformation, namespace below).
UNECE_NAMESPACE = "http://www.opcfoundation.org/UA/units/un/cefact"
UNITS = {"m": (5067858, "metre"), "V": (5655636, "volt"), "s": (5457219, "second")}
#: OPC 40502's enumerations, by value.
AXIS_STATUS = {"InPosition": 0, "Moving": 1, "Parked": 2}
CHANNEL_STATUS = {"Active": 0, "Interrupted": 1, "Reset": 2}
PROGRAM_STATUS = {"Stopped": 0, "Running": 1, "Waiting": 2, "Interrupted": 3, "Canceled": 4}
#: The run states of ``GantryTwin.RunState``.
RUN_STATES = ("idle", "running", "finished", "failed")
TWIN = "GantryTwin"


def node_id(path: str, namespace_index: int) -> ua.NodeId:
    """The string node id of the variable or object at ``path`` (``GantryTwin.SampleBlock``)."""
    return ua.NodeId(path, namespace_index)


def engineering_units(unit: str) -> ua.EUInformation:
    code, description = UNITS[unit]
    return ua.EUInformation(
        NamespaceUri=UNECE_NAMESPACE,
        UnitId=code,
        DisplayName=ua.LocalizedText(unit),
        Description=ua.LocalizedText(description),
    )


@dataclass
class AddressSpace:
    """The nodes a publisher writes, by their path (``CncInterface.CncAxisList.X.PosDirect.ActPos``)."""

    namespace_index: int
    twin: Node
    nodes: dict[str, Node] = field(default_factory=dict)

    def __getitem__(self, path: str) -> Node:
        return self.nodes[path]


class _Builder:
    def __init__(self, server: Server, idx: int) -> None:
        self.idx, self.nodes = idx, {}

    async def obj(self, parent: Node, path: str) -> Node:
        node = await parent.add_object(node_id(path, self.idx), ua.QualifiedName(path.rpartition(".")[2], self.idx))
        self.nodes[path] = node
        return node

    async def var(self, parent: Node, path: str, value: Any, vtype: ua.VariantType, unit: str | None = None) -> Node:
        name = path.rpartition(".")[2]
        node = await parent.add_variable(node_id(path, self.idx), ua.QualifiedName(name, self.idx), value, vtype)
        await node.write_attribute(
            ua.AttributeIds.MinimumSamplingInterval, ua.DataValue(ua.Variant(0.0, ua.VariantType.Double))
        )
        if unit is not None:
            await node.add_property(
                node_id(f"{path}.EngineeringUnits", self.idx),
                ua.QualifiedName("EngineeringUnits", 0),
                engineering_units(unit),
            )
        self.nodes[path] = node
        return node

    async def prop(self, parent: Node, path: str, value: Any, vtype: ua.VariantType) -> Node:
        name = path.rpartition(".")[2]
        node = await parent.add_property(node_id(path, self.idx), ua.QualifiedName(name, self.idx), value, vtype)
        self.nodes[path] = node
        return node


async def build_address_space(server: Server, scenario: str, plant: str, controller: str, ts: float) -> AddressSpace:
    """Add the twin's objects to ``server`` (before it starts); their nodes by path."""
    idx = await server.register_namespace(NAMESPACE)
    b = _Builder(server, idx)
    D, S, I32, I64 = ua.VariantType.Double, ua.VariantType.String, ua.VariantType.Int32, ua.VariantType.Int64
    cnc = await b.obj(server.nodes.objects, "CncInterface")
    axes = await b.obj(cnc, "CncInterface.CncAxisList")
    for axis in AXES:
        a = await b.obj(axes, a_path(axis))
        await b.var(a, f"{a_path(axis)}.ActStatus", AXIS_STATUS["Parked"], I32)
        for pos in ("PosDirect", "PosIndirect"):
            p = await b.var(a, f"{a_path(axis)}.{pos}", 0.0, D, "m")
            for leaf in ("ActPos", "CmdPos", "RemDist"):
                await b.var(p, f"{a_path(axis)}.{pos}.{leaf}", 0.0, D, "m")
    channels = await b.obj(cnc, "CncInterface.CncChannelList")
    ch = await b.obj(channels, "CncInterface.CncChannelList.Channel1")
    await b.var(ch, f"{CHANNEL}.ActStatus", CHANNEL_STATUS["Reset"], I32)
    await b.var(ch, f"{CHANNEL}.ActProgramStatus", PROGRAM_STATUS["Stopped"], I32)
    await b.var(ch, f"{CHANNEL}.ActProgramName", scenario, S)

    twin = await b.obj(server.nodes.objects, TWIN)
    await twin.write_attribute(
        ua.AttributeIds.EventNotifier, ua.DataValue(ua.Variant(1, ua.VariantType.Byte))
    )  # SubscribeToEvents: the health alarms
    await b.var(twin, f"{TWIN}.RunState", "idle", S)
    await b.var(twin, f"{TWIN}.Scenario", scenario, S)
    await b.var(twin, f"{TWIN}.Plant", plant, S)
    await b.var(twin, f"{TWIN}.Controller", controller, S)
    await b.var(twin, f"{TWIN}.SamplePeriod", ts, D, "s")
    await b.var(twin, f"{TWIN}.RunStartedAt", 0.0, D, "s")  # wall clock (s since 1970) when this pass's t = 0
    await b.var(twin, f"{TWIN}.RealtimeFactor", 0.0, D)  # sim time / wall time; 0: as fast as it runs
    await b.var(twin, f"{TWIN}.SampleIndex", -1, I64)
    await b.var(twin, f"{TWIN}.Time", 0.0, D, "s")
    await b.var(twin, f"{TWIN}.ContourError", 0.0, D, "m")
    await b.var(twin, f"{TWIN}.Command", [0.0, 0.0], D, "V")
    theta = await b.var(twin, f"{TWIN}.Theta", [float("nan")] * len(THETA_NAMES), D)
    await b.prop(theta, f"{TWIN}.Theta.ThetaNames", list(THETA_NAMES), S)
    await b.prop(theta, f"{TWIN}.Theta.ThetaUnits", list(THETA_UNITS), S)
    await b.var(twin, f"{TWIN}.Trusted", [False] * len(THETA_NAMES), ua.VariantType.Boolean)
    block = await b.var(twin, f"{TWIN}.SampleBlock", [], D)  # empty until the first block
    await b.prop(block, f"{TWIN}.SampleBlock.BlockSignals", [name for name, _ in SIGNALS], S)
    await b.prop(block, f"{TWIN}.SampleBlock.BlockUnits", [unit for _, unit in SIGNALS], S)
    await b.var(twin, f"{TWIN}.SamplesPublished", 0, I64)
    return AddressSpace(idx, twin, b.nodes)


def a_path(axis: str) -> str:
    """The browse path of an axis' object: ``x`` -> ``CncInterface.CncAxisList.X``."""
    return f"CncInterface.CncAxisList.{axis.upper()}"


CHANNEL = "CncInterface.CncChannelList.Channel1"
