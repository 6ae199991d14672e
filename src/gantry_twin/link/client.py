"""The OPC UA side of ``monitor --opcua``: a client in a thread of its own that subscribes to a machine's nodes
(:mod:`gantry_twin.link.nodemap`) and hands what comes to the caller's thread as :class:`Received` items,
reconnecting with backoff when the connection is lost (docs/live-link.md).

Subscriptions ask for a sampling interval of 0 (every change) and a queue of :data:`QUEUE_SIZE` values per
monitored item, so that no block is dropped between two publishing intervals of :data:`PUBLISHING_INTERVAL_MS`
(about 5 blocks in that time at real time, 20 at 4x).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import queue
import threading
import time
from dataclasses import dataclass
from typing import Any

from asyncua import Client, ua

from gantry_twin.link.address_space import UNITS
from gantry_twin.link.blocks import SIGNALS, BlockError, decode
from gantry_twin.link.nodemap import NodeMap

#: The publishing interval asked for, ms.
PUBLISHING_INTERVAL_MS = 100
#: Values queued per monitored item between two publications (blocks: 10 s at real time).
QUEUE_SIZE = 500
#: Waits between reconnection attempts, s (then the last, again).
BACKOFF_S = (0.5, 1.0, 2.0, 4.0)
#: How long one connection attempt may take, s.
CONNECT_TIMEOUT_S = 4.0


def asyncua_client(endpoint: str, timeout_s: float) -> Client:
    """An asyncua client whose requests, and whose probe of the server's state, may take ``timeout_s``.

    asyncua probes the server's state every ``watchdog_intervall`` s and takes a probe unanswered for as long
    for a lost connection. Its default, 1 s, took a loaded machine's server that answered late for a lost one:
    a gap and a reconnect where no sample was missing."""
    return Client(endpoint, timeout=timeout_s, watchdog_intervall=timeout_s)


class ClientError(ValueError):
    """What the machine's server said or lacks, in one line (a node that does not exist, a wrong unit)."""


@dataclass(frozen=True)
class Received:
    """One thing from the machine: ``kind`` block (value: a Block), scalar (name, value, SourceTimestamp in s),
    state (value: the run state), connected (value: the sample period the server says, or None), pace (after
    each connected; value: the machine's time per wall-clock second, or None where not known), lost (value:
    why), error (value: the one-line message: the stream cannot go on)."""

    kind: str
    value: Any
    name: str = ""
    time_s: float = 0.0


class MachineClient:
    """Subscribes to ``nodes`` on ``endpoint`` in a thread of its own; :meth:`get` the next :class:`Received`.
    ``first_connect_s``: how long to keep trying before the first connection (then an error item)."""

    def __init__(self, endpoint: str, nodes: NodeMap, first_connect_s: float = 10.0) -> None:
        self.endpoint, self.nodes, self.first_connect_s = endpoint, nodes, float(first_connect_s)
        self.items: queue.Queue[Received] = queue.Queue()
        self._stop = threading.Event()
        self._connected = False
        self._thread = threading.Thread(target=self._run, name="opcua-client", daemon=True)

    def start(self) -> MachineClient:
        self._thread.start()
        return self

    def get(self, timeout_s: float) -> Received | None:
        try:
            return self.items.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(15.0)

    # -- the client's thread --
    def _run(self) -> None:
        for name in ("asyncua", "asyncua.client", "asyncua.client.ua_client", "asyncua.common.subscription"):
            logging.getLogger(name).setLevel(logging.CRITICAL)
        try:
            asyncio.run(self._main())
        except Exception as exc:  # a bug here must not hang the caller: it ends the stream with the reason
            self.items.put(Received("error", f"opcua client: {type(exc).__name__}: {exc}"))

    async def _main(self) -> None:
        deadline = time.monotonic() + self.first_connect_s
        connected_once, attempt = False, 0
        while not self._stop.is_set():
            try:
                await self._session()
                return  # stopped by the caller
            except ClientError as exc:
                self.items.put(Received("error", str(exc)))
                return
            except (OSError, TimeoutError, ua.UaError, ConnectionError) as exc:
                why = _one_line(exc)
            if self._connected:
                connected_once = True
                self.items.put(Received("lost", why))
                attempt = 0
            elif not connected_once and time.monotonic() >= deadline:
                self.items.put(
                    Received(
                        "error",
                        f"--opcua {self.endpoint}: no machine answered within {self.first_connect_s:g} s ({why})",
                    )
                )
                return
            wait = BACKOFF_S[min(attempt, len(BACKOFF_S) - 1)]
            attempt += 1
            await asyncio.sleep(wait)

    async def _session(self) -> None:
        self._connected = False
        client = asyncua_client(self.endpoint, CONNECT_TIMEOUT_S)
        await asyncio.wait_for(client.connect(auto_reconnect=False), CONNECT_TIMEOUT_S + 1)
        try:
            self._connected = True
            nodes = await self._resolve(client)
            period = await self._period(client)
            self.items.put(Received("connected", period))
            self.items.put(Received("pace", await self._pace(client)))
            handler = _Handler(self)
            subscription = await client.create_subscription(PUBLISHING_INTERVAL_MS, handler)
            handler.by_node = {node.nodeid: name for name, node in nodes.items()}
            await subscription.create_monitored_items(
                [_every_value(node, h) for h, node in enumerate(nodes.values(), 1)]
            )
            while not self._stop.is_set():
                await asyncio.sleep(0.25)
                await asyncio.wait_for(client.check_connection(), CONNECT_TIMEOUT_S)
        finally:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(client.disconnect(), 3.0)

    async def _resolve(self, client: Client) -> dict[str, Any]:
        """The nodes to subscribe to, by signal name; ClientError naming a node the server does not have or whose
        unit is not the declared one."""
        m = self.nodes
        wanted: dict[str, str] = {}
        if m.blocks:
            wanted["block"] = m.blocks
        else:
            wanted.update({name: signal.node for name, signal in m.signals.items()})
        if m.run_state:
            wanted["state"] = m.run_state
        out = {}
        for name, text in wanted.items():
            try:
                node = client.get_node(await _node_id(client, text))
                await node.read_browse_name()
            except (ua.UaError, ValueError) as exc:
                raise ClientError(f"--opcua {self.endpoint}: node {text} ({name}): {_one_line(exc)}") from None
            out[name] = node
        if m.blocks:
            units = await _child_value(out["block"], "BlockUnits")
            expected = [unit for _, unit in SIGNALS]
            if units is not None and list(units) != expected:
                raise ClientError(
                    f"--opcua {self.endpoint}: node {m.blocks}: BlockUnits {list(units)} is not the expected {expected}"
                )
        else:
            for name, signal in m.signals.items():
                eu = await _child_value(out[name], "EngineeringUnits")
                code = UNITS.get(signal.unit, (None,))[0]
                if eu is not None and getattr(eu, "UnitId", code) != code:
                    shown = getattr(getattr(eu, "DisplayName", None), "Text", None) or eu.UnitId
                    raise ClientError(
                        f"--opcua {self.endpoint}: node {signal.node} ({name}): its EngineeringUnits are {shown}, "
                        f"the node map declares {signal.unit}"
                    )
        return out

    async def _period(self, client: Client) -> float | None:
        if self.nodes.sample_period_s is not None:
            return self.nodes.sample_period_s
        from gantry_twin.link.address_space import TWIN
        from gantry_twin.link.nodemap import twin_node

        try:
            return float(await client.get_node(await _node_id(client, twin_node(f"{TWIN}.SamplePeriod"))).read_value())
        except (ua.UaError, ValueError, TypeError):
            return None

    async def _pace(self, client: Client) -> float | None:
        """The machine's time per wall-clock second: a gantry-twin serve's ``RealtimeFactor`` (None where it is 0:
        as fast as it runs, or no pass started yet); 1 for a server without it (a machine runs in real time)."""
        from gantry_twin.link.address_space import TWIN
        from gantry_twin.link.nodemap import twin_node

        try:
            node = client.get_node(await _node_id(client, twin_node(f"{TWIN}.RealtimeFactor")))
            factor = float(await node.read_value())
        except (ValueError, TypeError, ua.UaError):  # no twin namespace, or no such node: a machine
            return 1.0
        return factor if 0.0 < factor < math.inf else None


class _Handler:
    def __init__(self, owner: MachineClient) -> None:
        self.owner, self.by_node = owner, {}

    def datachange_notification(self, node, value, data) -> None:
        name = self.by_node.get(node.nodeid)
        put = self.owner.items.put
        if name == "block":
            try:
                block = decode(value)
            except BlockError as exc:
                put(Received("error", f"--opcua {self.owner.endpoint}: {exc}"))
                return
            if block is not None:
                put(Received("block", block))
            return
        if name == "state":
            put(Received("state", str(value)))
        elif name is not None:
            stamp = data.monitored_item.Value.SourceTimestamp
            put(Received("scalar", value, name, stamp.timestamp() if stamp is not None else time.time()))

    def status_change_notification(self, status) -> None:
        self.owner.items.put(Received("lost", f"subscription status {status}"))


def _every_value(node, handle: int) -> ua.MonitoredItemCreateRequest:
    """A monitored item that reports every value the server writes: sampling interval 0 (asyncua's client asks
    50 ms unless told, and a server that samples then drops the blocks between), a queue of QUEUE_SIZE, and the
    trigger StatusValueTimestamp (the default, StatusValue, reports a value only when it differs from the last:
    a machine standing still, or a constant command, would lose its samples)."""
    parameters = ua.MonitoringParameters(
        ClientHandle=handle,
        SamplingInterval=0.0,
        QueueSize=QUEUE_SIZE,
        DiscardOldest=True,
        Filter=ua.DataChangeFilter(Trigger=ua.DataChangeTrigger.StatusValueTimestamp),
    )
    return ua.MonitoredItemCreateRequest(
        ItemToMonitor=ua.ReadValueId(NodeId=node.nodeid, AttributeId=ua.AttributeIds.Value),
        MonitoringMode=ua.MonitoringMode.Reporting,
        RequestedParameters=parameters,
    )


async def _node_id(client: Client, text: str) -> ua.NodeId:
    """``nsu=URI;s=Name`` resolved to the server's index; any other text form parsed as it is."""
    if text.startswith("nsu="):
        uri, _, rest = text[4:].partition(";")
        try:
            index = await client.get_namespace_index(uri)
        except ValueError:
            raise ValueError(f"the server has no namespace {uri}") from None
        text = f"ns={index};{rest}"
    return ua.NodeId.from_string(text)


async def _child_value(node, name: str) -> Any:
    for child in await node.get_properties():
        if (await child.read_browse_name()).Name == name:
            return await child.read_value()
    return None


def _one_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__
