"""End-stop events and command saturation (gantry_twin.loop.events), in simulate and on the command line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import register, unregister
from gantry_twin.loop.events import EVENTS_MAX, TravelWatch, travel_summary

from .helpers import DAC_LIMIT_V, TRAVEL_END_M, pushed_from_rest_m, run_main

#: The controller's sample period, s (docs/equations.md, sensing).
TS = 2e-4
#: A short run on the command line: (duration s, --set overrides). 0.2 s = 1000 samples.
SHORT = ("duration_s=0.2", "window_s=[0.1,0.2]", "estimates_window_s=[0.1,0.2]", "monitor.baseline_window_s=[0.1,0.2]")
SHORT_SAMPLES = 1000


class Schedule:
    """A plug-in that applies piecewise-constant volts: ``steps`` = [(from_s, [u_x, u_y]), ...] in time order."""

    def __init__(self, steps=((0.0, (0.0, 0.0)),)):
        self.steps = [(float(t), np.asarray(u, dtype=float)) for t, u in steps]

    def reset(self, context):
        pass

    def update(self, measurement, reference):
        volts = self.steps[0][1]
        for t, u in self.steps:
            if measurement.t_s >= t - 1e-12:
                volts = u
        return volts.copy()

    def state_for_logging(self):
        return {}


class Pulses:
    """A plug-in that sends ``saturated_x`` / ``saturated_y`` commands at or beyond the DAC limit, the rest inside it.

    The saturating samples are chosen at random (seeded); their signs alternate so
    that the carriages stay put; in between it sends commands just inside the limit.
    ``sent`` counts, per axis, the saturating commands it returned.
    """

    BEYOND = (DAC_LIMIT_V, -2 * DAC_LIMIT_V, 1e300, -DAC_LIMIT_V)  # each at or past the limit

    def __init__(self, saturated_x=0, saturated_y=0, samples=SHORT_SAMPLES, seed=3):
        rng = np.random.default_rng(seed)
        self.at = [set(rng.choice(samples, size=n, replace=False).tolist()) for n in (saturated_x, saturated_y)]
        self.sent = np.zeros(2, dtype=int)
        self.calls = 0

    def reset(self, context):
        self.calls = 0
        self.sent[:] = 0

    def update(self, measurement, reference):
        u = np.empty(2)
        for i in range(2):
            if self.calls in self.at[i]:
                u[i] = self.BEYOND[self.sent[i] % len(self.BEYOND)]
                self.sent[i] += 1
            else:
                u[i] = (DAC_LIMIT_V - 1e-9) * (-1) ** self.calls  # just inside: not saturated
        self.calls += 1
        return u

    def state_for_logging(self):
        return {}


@pytest.fixture
def plugin():
    """Register plug-ins for the command line for one test: plugin(name, factory)."""
    names = []

    def add(name, factory):
        register(name, factory)
        names.append(name)

    yield add
    for name in names:
        unregister(name)


def arrival_s(start_m: float, end_m: float, axis: int, volts: float) -> float:
    """When the reference machine, pushed from rest at start_m, reaches end_m (s)."""
    fine = np.arange(0.0, 1.0, 1e-6)
    moved = start_m + pushed_from_rest_m(fine, axis, volts)
    return float(fine[np.argmax(np.sign(volts) * (moved - end_m) >= 0)])


def push_both(duration_s=0.35, observers=(), chunk_s=0.1):
    """From rest at the circle's start (0, -0.2) m: X driven at +10 V to its + end, Y at -10 V to its - end."""
    plant = Plant()
    controller = Schedule([(0.0, (DAC_LIMIT_V, -DAC_LIMIT_V))])
    trace = simulate(
        plant, circle(), TimingLaw(2.0, "rest"), controller, duration_s, observers=observers, chunk_s=chunk_s
    )
    return plant, trace


def test_an_end_stop_event_says_when_and_where():
    plant, trace = push_both()
    assert trace.q_m[0].tolist() == [0.0, -0.2]  # the start the computation below assumes
    data = travel_summary(plant, trace)
    events = data["events"]
    assert data["end_stop_contacts"] == {"x": 1, "y": 1}
    assert [e["t_s"] for e in events] == sorted(e["t_s"] for e in events)
    for axis, start, end, volts in ((0, 0.0, TRAVEL_END_M, DAC_LIMIT_V), (1, -0.2, -TRAVEL_END_M, -DAC_LIMIT_V)):
        (event,) = [e for e in events if e["axis"] == "xy"[axis]]
        assert event["kind"] == "end_stop"
        assert event["end_m"] == end
        # It touched the stop between reaching 1 mm before the end and reaching the end (plus a sample).
        earliest = arrival_s(start, end - np.sign(end) * 1e-3, axis, volts)
        latest = arrival_s(start, end, axis, volts) + TS
        assert earliest <= event["t_s"] <= latest
        # Exactly: the first sample inside the zone where MuJoCo's limit acts (the joint's margin inside the end).
        margin = plant.model.jnt_margin[plant.model.joint("xy"[axis]).id]
        first = np.argmax(np.abs(trace.q_m[:, axis] - end) < margin)
        assert event["t_s"] == trace.t_s[first]
        # The furthest position is the trace's, within 1 mm of the end; the carriage stayed on the stop.
        q = trace.q_m[:, axis]
        assert event["position_m"] == (q.max() if end > 0 else q.min())
        assert abs(event["position_m"] - end) <= 1e-3
        assert event["left_s"] is None


def test_no_event_before_the_carriage_gets_there():
    t_x = arrival_s(0.0, TRAVEL_END_M - 1e-3, 0, DAC_LIMIT_V)
    t_y = arrival_s(-0.2, -TRAVEL_END_M + 1e-3, 1, -DAC_LIMIT_V)
    plant, trace = push_both(duration_s=min(t_x, t_y) - TS)
    data = travel_summary(plant, trace)
    assert data["events"] == [] and data["end_stop_contacts"] == {"x": 0, "y": 0}


def test_watching_chunk_by_chunk_finds_what_the_whole_trace_shows():
    """Contacts that span chunks: an Observer with odd-sized chunks reports exactly what the finished trace does."""
    plant = Plant()
    bang = Schedule([(0.0, (DAC_LIMIT_V, 0.0)), (0.12, (-DAC_LIMIT_V, 0.0)), (0.14, (DAC_LIMIT_V, 0.0))])
    watch = TravelWatch(plant)
    trace = simulate(plant, circle(), TimingLaw(2.0, "rest"), bang, 0.3, observers=[watch], chunk_s=0.0007)
    whole = travel_summary(plant, trace)
    assert whole["end_stop_contacts"]["x"] == 2
    assert watch.summary() == whole


def test_events_listed_are_capped_but_all_counted():
    """A carriage chattering in and out of its stop: the first EVENTS_MAX contacts listed, every one counted."""
    plant = Plant()
    n_contacts = EVENTS_MAX + 30
    t = np.arange(4 * n_contacts) * TS
    q = np.zeros((t.size, 2))
    q[1::4, 0] = TRAVEL_END_M  # X on the + end every fourth sample
    q[3::4, 1] = -TRAVEL_END_M  # Y on the - end every fourth sample
    u = np.zeros((t.size, 2))
    whole = TravelWatch(plant)
    whole.scan(t, q, u)
    data = whole.summary()
    assert data["end_stop_contacts"] == {"x": n_contacts, "y": n_contacts}
    assert len(data["events"]) == EVENTS_MAX
    assert [e["t_s"] for e in data["events"]] == t[1 : 2 * EVENTS_MAX : 2].tolist()  # x, y, x, y, ...
    for size in (1, 2, 7):  # contacts that end exactly at a chunk's end, and inside one
        chunked = TravelWatch(plant)
        for start in range(0, t.size, size):
            chunked.scan(t[start : start + size], q[start : start + size], u[start : start + size])
        assert chunked.summary() == data


@pytest.mark.parametrize(("saturated_x", "saturated_y"), [(0, 0), (37, 3), (1000, 500)])
def test_saturation_fraction_counts_the_commands_at_the_limit(saturated_x, saturated_y):
    controller = Pulses(saturated_x, saturated_y)
    plant = Plant()
    trace = simulate(plant, circle(), TimingLaw(2.0), controller, SHORT_SAMPLES * TS)
    saturation = travel_summary(plant, trace)["saturation"]
    assert saturation["x"]["fraction"] == saturated_x / SHORT_SAMPLES
    assert saturation["y"]["fraction"] == saturated_y / SHORT_SAMPLES
    assert controller.sent.tolist() == [saturated_x, saturated_y]
    assert saturation["x"]["limit_v"] == [-DAC_LIMIT_V, DAC_LIMIT_V]


def cli_args(command, controller, out, *extra):
    scenario = ["no_load_circle"] if command == "monitor" else []
    sets = [x for s in SHORT for x in ("--set", s)]
    return [command, *scenario, "--controller", controller, *sets, "--out", str(out), "--no-progress", *extra]


@pytest.mark.parametrize("command", ["run", "monitor"])
def test_cli_reports_an_end_stop_and_strict_makes_it_an_error(tmp_path, capsys, plugin, command):
    from gantry_twin.cli.app import EXIT_END_STOP, EXIT_NOT_JUDGED, EXIT_OK

    plugin("push_x", lambda: Schedule([(0.0, (DAC_LIMIT_V, 0.0))]))
    code, _, err = run_main(cli_args(command, "push_x", tmp_path / "a"), capsys)
    # a plug-in that estimates nothing gives the monitor nothing to judge: not a healthy verdict
    assert code == (EXIT_OK if command == "run" else EXIT_NOT_JUDGED)
    (event,) = json.loads((tmp_path / "a" / "summary.json").read_text())["events"]
    lines = [line for line in err.splitlines() if "end stop" in line]
    assert len(lines) == 1
    assert lines[0].startswith("gantry-twin: warning: end stop: the X carriage") and "Y carriage" not in err
    assert f"t = {event['t_s']:.4f} s" in lines[0]

    code, _, err = run_main(cli_args(command, "push_x", tmp_path / "b", "--strict"), capsys)
    assert code == EXIT_END_STOP
    assert "end stop: the X carriage" in err
    assert (tmp_path / "b" / "summary.json").is_file()  # the run's files are written all the same


def test_strict_passes_a_run_that_stays_inside_the_travel(tmp_path, capsys):
    code, _, err = run_main(cli_args("run", "diarc", tmp_path, "--strict"), capsys)
    assert code == 0
    assert "warning" not in err
    data = json.loads((tmp_path / "summary.json").read_text())
    assert data["events"] == [] and data["end_stop_contacts"] == {"x": 0, "y": 0}
    assert data["saturation"]["x"]["fraction"] == 0.0 and data["saturation"]["y"]["fraction"] == 0.0


@pytest.mark.parametrize(("saturated", "warned"), [(5, False), (10, False), (11, True), (600, True)])
def test_saturation_warning_above_one_percent(tmp_path, capsys, plugin, saturated, warned):
    plugin("pulses", Pulses)
    args = cli_args("run", "pulses", tmp_path, "--set", f"controller.options.saturated_x={saturated}")
    code, _, err = run_main(args, capsys)
    assert code == 0
    fraction = json.loads((tmp_path / "summary.json").read_text())["saturation"]["x"]["fraction"]
    assert fraction == saturated / SHORT_SAMPLES
    lines = [line for line in err.splitlines() if "saturation" in line]
    assert len(lines) == (1 if warned else 0)
    if warned:
        assert lines[0].startswith("gantry-twin: warning: saturation: the X command")
        assert f"{100 * fraction:.2f} %" in lines[0]
    assert "Y command" not in err
