"""The twin served as a machine over OPC UA: ``gantry-twin serve`` (docs/live-link.md).

The run goes on in the caller's thread, chunk by chunk, as ``gantry-twin run`` runs it; :class:`LinkObserver`
takes each finished chunk's samples (never inside the compiled loop: it is an observer, as the rerun one is)
and hands them to :class:`TwinServer`, whose asyncua server runs in a thread of its own with its own event
loop. About every :data:`PUBLISH_PERIOD_S` of wall time the server publishes what came since as one or more
sample blocks (:mod:`gantry_twin.link.blocks`), so that a subscriber gets every sample whatever the pace (at
``--realtime 1`` a block holds about 100 samples; at ``--realtime max`` more), and updates the decimated scalar
view for HMIs at most :data:`SCALAR_PERIOD_S` apart. The health monitor's alarms become events.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime
import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from asyncua import Server, ua

from gantry_twin.link.address_space import (
    AXIS_STATUS,
    CHANNEL,
    CHANNEL_STATUS,
    PROGRAM_STATUS,
    TWIN,
    AddressSpace,
    a_path,
    build_address_space,
)
from gantry_twin.link.blocks import SIGNAL_NAMES, Block, trace_values
from gantry_twin.link.security import Security
from gantry_twin.loop.trace import RunInfo, SimulationError, Trace
from gantry_twin.theta import AXES, THETA_NAMES

#: Wall time between two publications of the samples that came, s (about 50 blocks a second at real time).
PUBLISH_PERIOD_S = 0.02
#: Wall time between two updates of the scalar view, s.
SCALAR_PERIOD_S = 0.1
#: The most samples in one block (a block is one message: at most this many x 18 doubles).
MAX_SAMPLES_PER_BLOCK = 5000
#: Chunks of samples the loop may be ahead of the publisher before it waits (the run slows; no sample is dropped).
QUEUE_CHUNKS = 500
#: The largest message the server takes or sends, bytes (a block of MAX_SAMPLES_PER_BLOCK is 0.7 MB).
MAX_MESSAGE_BYTES = 8 * 1024 * 1024
#: The most subscriptions at once, over all sessions.
MAX_SUBSCRIPTIONS = 200
#: The most monitored items in one subscription (the twin's own object and the CNC axes have about 60 variables),
#: and over all subscriptions: each monitored item of a changing variable costs the server's thread about 30 us per
#: update, so an unbounded count would take the core the run needs (docs/live-link.md, "Hostile clients").
MAX_MONITORED_ITEMS_PER_SUBSCRIPTION = 100
MAX_MONITORED_ITEMS = 400
#: The longest a session may stay idle before the server closes it (a client asks; it gets at most this), ms.
SESSION_TIMEOUT_MS = 30_000
#: Alarm severity (OPC UA: 1-1000) of a health alarm.
ALARM_SEVERITY = 700
IDX = {name: i for i, name in enumerate(SIGNAL_NAMES)}


class SharedValue(ua.DataValue):
    """A written value the server never changes, shared by every monitored item of its variable: asyncua
    deep-copies the value it hands to each monitored item (26 us for a scalar, 0.4 ms for a block of 100 samples,
    element by element, measured), which made 1000 monitored items on one position cost the server's thread
    half a core at real time. It encodes as a DataValue (the encoder goes by the field's declared type)."""

    def __deepcopy__(self, memo: dict) -> SharedValue:
        return self


class LinkError(RuntimeError):
    """The server cannot start or run; the message is one line."""


@dataclass(frozen=True)
class Served:
    """What the address space says of the run: the scenario's name, the plant's label, the controller, Ts (s)."""

    scenario: str
    plant: str
    controller: str
    sample_period_s: float


class TwinServer:
    """An asyncua server in a thread of its own, fed samples by :class:`LinkObserver`.

    ``with TwinServer(...) as server:`` starts it (LinkError if it cannot listen) and stops it at the end,
    closing every session.
    """

    def __init__(self, served: Served, host: str, port: int, security: Security) -> None:
        self.served, self.host, self.port, self.security = served, host, int(port), security
        self._queue: queue.Queue = queue.Queue(maxsize=QUEUE_CHUNKS)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._started = threading.Event()
        self._stopped = threading.Event()
        self._error: BaseException | None = None
        self.commands: queue.Queue[str] = queue.Queue()  # Start, Stop, Reset from clients with the operator role

    def next_command(self, timeout_s: float) -> str | None:
        """The next Start, Stop or Reset a client called, waiting at most ``timeout_s``; None if none came."""
        try:
            return self.commands.get(timeout=max(0.0, timeout_s))
        except queue.Empty:
            return None
        self.space: AddressSpace | None = None
        self.bound_port = self.port  # the port listened on (the one chosen when ``port`` is 0)
        #: CPU seconds of the server's own thread (set when it stops): what serving costs besides the hand-over.
        self.thread_cpu_s = 0.0

    @property
    def endpoint(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"opc.tcp://{host}:{self.port}"

    # -- the caller's side (any thread) --
    def __enter__(self) -> TwinServer:
        self._thread = threading.Thread(target=self._serve, name="opcua-server", daemon=True)
        self._thread.start()
        self._started.wait(60.0)
        if self._error is not None:
            raise LinkError(f"serve: cannot listen on {self.endpoint}: {_one_line(self._error)}") from None
        if not self._started.is_set():
            raise LinkError(f"serve: the server on {self.endpoint} did not start within 60 s")
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def put(self, item: tuple) -> None:
        """Hand an item to the publisher; waits (the run slows) while the publisher is QUEUE_CHUNKS behind."""
        while not self._stopped.is_set():
            try:
                self._queue.put(item, timeout=0.5)
                return
            except queue.Full:
                continue

    def subscribers(self) -> int:
        """Subscriptions that monitor at least one item now (read from the server's thread's state)."""
        service = getattr(getattr(self, "_server", None), "iserver", None)
        subscriptions = getattr(getattr(service, "subscription_service", None), "subscriptions", {})
        count = 0
        for subscription in list(subscriptions.values()):
            items = getattr(getattr(subscription, "monitored_item_srv", None), "_monitored_items", {})
            count += bool(items)
        return count

    def wait_for_subscribers(self, count: int, timeout_s: float) -> bool:
        """Wait (bounded) until ``count`` subscriptions monitor something; False if they did not come in time."""
        deadline = time.monotonic() + timeout_s
        while self.subscribers() < count:
            if time.monotonic() >= deadline or self._stopped.is_set():
                return False
            time.sleep(0.05)
        return True

    def drain(self, timeout_s: float = 10.0) -> None:
        """Wait until everything handed over so far is published (bounded by ``timeout_s``)."""
        done = threading.Event()
        self.put(("mark", done))
        done.wait(timeout_s)

    def close(self) -> None:
        if self._loop is not None and not self._stopped.is_set():
            self._loop.call_soon_threadsafe(self._stop_requested.set)
        if self._thread is not None:
            self._thread.join(30.0)

    # -- the server's thread --
    def _serve(self) -> None:
        try:
            asyncio.run(self._main())
        except BaseException as exc:  # reported by __enter__, or logged when it comes later
            self._error = exc
        finally:
            self._stopped.set()
            self._started.set()

    async def _main(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop_requested = asyncio.Event()
        for name in ("asyncua", "asyncua.server", "asyncua.server.uaprocessor", "asyncua.server.binary_server_asyncio"):
            logging.getLogger(name).setLevel(logging.CRITICAL)  # a hostile client's noise is not the user's
        server = Server(user_manager=self.security.user_manager())
        await server.init()
        server.set_endpoint(self.endpoint)
        server.set_server_name("gantry-twin")
        await self.security.apply(server)
        server.iserver.max_session_timeout_ms = SESSION_TIMEOUT_MS  # an idle session is closed after it
        self._limit(server)
        self.space = await build_address_space(
            server, self.served.scenario, self.served.plant, self.served.controller, self.served.sample_period_s
        )
        await self._add_methods(server)
        self._alarms = await server.get_event_generator(ua.ObjectIds.AlarmConditionType, self.space.twin)
        self._server = server
        async with server:
            self.bound_port = server.bserver.port if server.bserver is not None else self.port
            self._started.set()
            publisher = asyncio.create_task(self._publish())
            await self._stop_requested.wait()
            publisher.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await publisher
        self.thread_cpu_s = time.thread_time()  # this thread's CPU, all of it the server's

    def _limit(self, server: Server) -> None:
        """Bounds against a hostile client: messages of at most MAX_MESSAGE_BYTES (asyncua's default is 100 MB),
        at most MAX_SUBSCRIPTIONS subscriptions in all, monitored items as :func:`_cap_monitored_items` says."""
        from asyncua.common.connection import TransportLimits

        chunk = 65535
        server.limits = TransportLimits(
            max_recv_buffer=chunk,
            max_send_buffer=chunk,
            max_chunk_count=MAX_MESSAGE_BYTES // chunk + 1,
            max_message_size=MAX_MESSAGE_BYTES,
        )
        server.iserver.max_subscriptions = MAX_SUBSCRIPTIONS
        _cap_monitored_items(server.iserver.subscription_service)

    async def _add_methods(self, server: Server) -> None:
        assert self.space is not None
        idx = self.space.namespace_index
        for name in ("Start", "Stop", "Reset"):

            async def method(parent: ua.NodeId, name: str = name) -> list:
                self.commands.put(name)
                return []

            await self.space.twin.add_method(ua.NodeId(f"{TWIN}.{name}", idx), ua.QualifiedName(name, idx), method)

    async def _publish(self) -> None:
        pending: list[np.ndarray] = []
        next_scalars = 0.0
        last: np.ndarray | None = None
        while True:
            deadline = time.monotonic() + PUBLISH_PERIOD_S
            while True:
                try:
                    item = self._queue.get_nowait()
                except queue.Empty:
                    break
                kind = item[0]
                if kind == "samples":
                    pending.append(item[1])
                    continue
                last = await self._flush(pending, last)  # what came before the item goes first
                pending = []
                if kind == "state":
                    await self._state(item[1])
                elif kind == "started":
                    await self._write(f"{TWIN}.RunStartedAt", item[1], ua.VariantType.Double)
                    await self._write(f"{TWIN}.RealtimeFactor", item[2], ua.VariantType.Double)
                elif kind == "alarm":
                    await self._alarm(item[1])
                elif kind == "trusted":
                    await self._write(f"{TWIN}.Trusted", item[1], ua.VariantType.Boolean)
                elif kind == "mark":
                    item[1].set()
            last = await self._flush(pending, last)
            pending = []
            if last is not None and time.monotonic() >= next_scalars:
                await self._scalars(last)
                next_scalars = time.monotonic() + SCALAR_PERIOD_S
            await asyncio.sleep(max(0.0, deadline - time.monotonic()))

    async def _flush(self, pending: list[np.ndarray], last: np.ndarray | None) -> np.ndarray | None:
        if not pending:
            return last
        values = np.concatenate(pending)
        first = int(values[0, -1])  # the samples' global index rides in the last column until here
        for i in range(0, values.shape[0], MAX_SAMPLES_PER_BLOCK):
            part = values[i : i + MAX_SAMPLES_PER_BLOCK]
            block = Block(first + i, float(part[0, 0]), part[:, :-1])
            await self._write(f"{TWIN}.SampleBlock", block.encode(), ua.VariantType.Double)
            await self._write(f"{TWIN}.SamplesPublished", block.end_index, ua.VariantType.Int64)
        return values[-1]

    async def _write(self, path: str, value: object, vtype: ua.VariantType) -> None:
        assert self.space is not None
        now = datetime.datetime.now(datetime.UTC)
        dv = SharedValue(ua.Variant(value, vtype), SourceTimestamp=now, ServerTimestamp=now)
        await self._server.write_attribute_value(self.space[path].nodeid, dv)

    async def _scalars(self, row: np.ndarray) -> None:
        D = ua.VariantType.Double
        await self._write(f"{TWIN}.SampleIndex", int(row[-1]), ua.VariantType.Int64)
        await self._write(f"{TWIN}.Time", float(row[IDX["t_s"]]), D)
        await self._write(f"{TWIN}.ContourError", float(row[IDX["eps_c_m"]]), D)
        await self._write(f"{TWIN}.Command", [float(row[IDX["u_x_v"]]), float(row[IDX["u_y_v"]])], D)
        await self._write(f"{TWIN}.Theta", [float(row[IDX[f"theta_hat_{n}"]]) for n in THETA_NAMES], D)
        for axis in AXES:
            cmd = float(row[IDX[f"{axis}_d_m"]])
            for pos, column in (("PosDirect", f"{axis}_meas_m"), ("PosIndirect", f"{axis}_m")):
                act = float(row[IDX[column]])
                base = f"{a_path(axis)}.{pos}"
                await self._write(base, act, D)
                await self._write(f"{base}.ActPos", act, D)
                await self._write(f"{base}.CmdPos", cmd, D)
                await self._write(f"{base}.RemDist", cmd - act, D)

    async def _state(self, state: str) -> None:
        I32 = ua.VariantType.Int32
        await self._write(f"{TWIN}.RunState", state, ua.VariantType.String)
        running = state == "running"
        for axis in AXES:
            status = AXIS_STATUS["Moving"] if running else AXIS_STATUS["InPosition"]
            await self._write(f"{a_path(axis)}.ActStatus", status, I32)
        channel = CHANNEL_STATUS["Active"] if running else CHANNEL_STATUS["Reset"]
        program = {"running": "Running", "finished": "Stopped", "failed": "Canceled", "idle": "Stopped"}[state]
        await self._write(f"{CHANNEL}.ActStatus", channel, I32)
        await self._write(f"{CHANNEL}.ActProgramStatus", PROGRAM_STATUS[program], I32)

    async def _alarm(self, message: str) -> None:
        event = self._alarms.event
        event.Message = ua.LocalizedText(message)
        event.Severity = ALARM_SEVERITY
        event.SourceName = TWIN
        await self._alarms.trigger(message=message)


def _cap_monitored_items(service) -> None:
    """Items past MAX_MONITORED_ITEMS_PER_SUBSCRIPTION in their subscription, or MAX_MONITORED_ITEMS in all, are
    refused with BadTooManyMonitoredItems (each in its own result, as OPC UA's CreateMonitoredItems answers); the
    rest are created. asyncua has no such limit of its own."""
    create = service.create_monitored_items

    def count(subscription) -> int:
        return len(getattr(getattr(subscription, "monitored_item_srv", None), "_monitored_items", {}))

    async def capped(params: ua.CreateMonitoredItemsParameters) -> list[ua.MonitoredItemCreateResult]:
        subscription = service.subscriptions.get(params.SubscriptionId)
        if subscription is None:
            return await create(params)  # asyncua's own answer: BadSubscriptionIdInvalid
        total = sum(count(s) for s in list(service.subscriptions.values()))
        room = max(0, min(MAX_MONITORED_ITEMS_PER_SUBSCRIPTION - count(subscription), MAX_MONITORED_ITEMS - total))
        items = list(params.ItemsToCreate)
        params.ItemsToCreate = items[:room]
        results = await create(params) if items[:room] else []
        refused = ua.StatusCode(ua.StatusCodes.BadTooManyMonitoredItems)
        return [*results, *(ua.MonitoredItemCreateResult(StatusCode=refused) for _ in items[room:])]

    service.create_monitored_items = capped


class LinkObserver:
    """Hands a run's finished chunks to a :class:`TwinServer` (an Observer of the loop, as the rerun one is).

    ``first_index`` and ``time_offset_s`` place this pass after the passes before it (``serve --loop``);
    ``realtime`` is the pace (0: as fast as it runs), published with the pass's start. The
    run's health monitor, when it has one, is watched: each new alarm becomes an event.
    """

    def __init__(
        self,
        server: TwinServer,
        first_index: int = 0,
        time_offset_s: float = 0.0,
        describe: Callable[[object], str] = str,
        realtime: float = 0.0,
    ) -> None:
        self.server, self.first_index, self.time_offset_s, self.describe = server, first_index, time_offset_s, describe
        self.realtime = realtime
        self.monitor = None
        self.cpu_s = 0.0  # CPU seconds of the run's thread spent handing chunks over (not counting a full queue's wait)
        self.stopped: str | None = None  # "Stop" or "Reset" when a client's method call ended the pass
        self._alarms_sent = 0
        self._periods_sent = 0  # the health monitor's periods whose trust flags are published
        self.end_index = first_index

    def watch(self, monitor: object) -> None:
        self.monitor = monitor

    def on_start(self, run: RunInfo, trace: Trace) -> None:
        self.server.put(("started", time.time(), self.realtime))  # before the pacer's own clock starts
        self.server.put(("state", "running"))

    def on_chunk(self, trace: Trace, start: int, stop: int) -> None:
        if stop <= start:
            return
        started = time.thread_time()
        try:
            self._hand_over(trace, start, stop)
        finally:
            self.cpu_s += time.thread_time() - started
        self._obey(trace, stop)

    def _obey(self, trace: Trace, stop: int) -> None:
        """A client's Stop or Reset (an operator's method call) ends this pass: SimulationError, so that the run's
        directory keeps what ran (status failed, the reason named); a Start while running is ignored."""
        while True:
            try:
                command = self.server.commands.get_nowait()
            except queue.Empty:
                return
            if command in ("Stop", "Reset"):
                self.stopped = command
                t = float(trace.t_s[stop - 1 - trace.first])
                raise SimulationError(f"stopped by a client's {command} (OPC UA method)", t, stop)

    def _hand_over(self, trace: Trace, start: int, stop: int) -> None:
        values = trace_values(trace, start, stop)
        values[:, IDX["t_s"]] += self.time_offset_s
        index = np.arange(self.first_index + start, self.first_index + stop, dtype=np.float64)
        self.server.put(("samples", np.column_stack([values, index])))
        self.end_index = self.first_index + stop
        if self.monitor is not None:
            alarms = self.monitor.alarms
            for alarm in alarms[self._alarms_sent :]:
                self.server.put(("alarm", self.describe(alarm)))
            self._alarms_sent = len(alarms)
            _, trusted = self.monitor.trusted_since(self._periods_sent)
            if trusted.shape[0]:  # the last period closed: each estimate excited and its bias within bounds
                self.server.put(("trusted", [bool(flag) for flag in trusted[-1]]))
                self._periods_sent += trusted.shape[0]

    def on_end(self, trace: Trace) -> None:
        pass


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__
