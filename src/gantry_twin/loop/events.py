"""What a run did to the machine beyond its task: end-stop contacts and command saturation.

**End stops.** Each joint's limit in ``models/gantry.xml`` is the travel end;
MuJoCo's limit constraint acts from ``margin`` inside it (the joint's
``jnt_range`` and ``jnt_margin``, read from the compiled model). A sample
whose true position lies in that zone touches an end stop, exactly when
MuJoCo's limit is active (``range[1] - q < margin``, or
``q - range[0] < margin``). One contact is a run of consecutive such samples;
its event gives the time of the first, the travel end and the furthest
position reached.

**Saturation.** The fraction of samples whose (clipped) command sits at the
control motor's ``ctrlrange`` limit (:attr:`gantry_twin.plant.model.Plant.ctrl_range_v`),
per axis; above :data:`SATURATION_WARNING_FRACTION` the command line warns.

:class:`TravelWatch` scans chunk by chunk (a simulate ``Observer``: it needs
no more of the trace than the chunk in hand); :func:`travel_summary` runs the
same scan over a finished trace, block by block, which is what
:func:`gantry_twin.run.write_run` does: a few vectorised comparisons per
sample, far below the cost of simulating them, with bounded memory, and no
object to carry from ``simulate`` to the writing (docs/performance.md). A
trace that is not held whole can have a ``TravelWatch`` among its observers
instead. The summary.json fields, the warnings and the ``--strict`` test are
read back from the summary alone (docs/cli.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from gantry_twin.loop.trace import RunInfo, Trace
from gantry_twin.plant.model import AXES, Plant

#: summary.json lists at most this many end-stop events (the first in time);
#: ``end_stop_contacts`` counts them all.
EVENTS_MAX = 100
#: The command line warns when an axis' command is at its limit in more than this fraction of samples.
SATURATION_WARNING_FRACTION = 0.01
#: The ``kind`` of an end-stop event in summary.json.
END_STOP = "end_stop"
#: :func:`travel_summary` scans a finished trace this many samples at a time (bounded temporaries).
SCAN_BLOCK = 1 << 16


def end_stop_zones(plant: Plant) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ends_m (2, 2) [[lo, hi], ...], lower_m (2,), upper_m (2,)) per axis (X, Y), metres.

    ends_m: the joint ranges (the travel ends); the end stops act below
    ``lower_m`` and above ``upper_m``: the range less the joint's margin.
    """
    model = plant.model
    joints = [model.joint(name).id for name in AXES]
    ends = model.jnt_range[joints].copy()
    margin = model.jnt_margin[joints]
    return ends, ends[:, 0] + margin, ends[:, 1] - margin


@dataclass
class EndStopEvent:
    """One contact with an end stop: from ``t_s`` (first sample in the stop's zone) to ``left_s``.

    end_m: the travel end touched (the joint's range), m; position_m: the
    furthest true position of the contact, m; left_s: the first sample out of
    the zone again, None if the run ended in contact.
    """

    t_s: float
    axis: str
    end_m: float
    position_m: float
    left_s: float | None = None

    def as_dict(self) -> dict[str, Any]:
        return {
            "t_s": self.t_s,
            "kind": END_STOP,
            "axis": self.axis,
            "end_m": self.end_m,
            "position_m": self.position_m,
            "left_s": self.left_s,
        }


class TravelWatch:
    """End-stop contacts and saturation of one run, chunk by chunk (an Observer; reads the trace only)."""

    def __init__(self, plant: Plant) -> None:
        self.ends_m, self.lower_m, self.upper_m = end_stop_zones(plant)
        self.ctrl_range_v = plant.ctrl_range_v
        self._reset()

    def _reset(self) -> None:
        self.events: list[list[EndStopEvent]] = [[] for _ in AXES]  # per axis, the first EVENTS_MAX
        self.contacts = np.zeros(len(AXES), dtype=int)
        self.saturated = np.zeros(len(AXES), dtype=int)
        self.samples = 0
        self._open: list[EndStopEvent | None] = [None] * len(AXES)  # the contact in progress per axis

    def on_start(self, run: RunInfo, trace: Trace) -> None:
        self._reset()

    def on_chunk(self, trace: Trace, start: int, stop: int) -> None:
        rows = trace.rows(start, stop)
        self.scan(trace.t_s[rows], trace.q_m[rows], trace.u_v[rows])

    def on_end(self, trace: Trace) -> None:
        pass

    def scan(self, t_s: np.ndarray, q_m: np.ndarray, u_v: np.ndarray) -> None:
        """The next samples: times (n,) s, true positions (n, 2) m, commands as applied (n, 2) V."""
        lo_v, hi_v = self.ctrl_range_v[:, 0], self.ctrl_range_v[:, 1]
        self.saturated += np.count_nonzero((u_v <= lo_v) | (u_v >= hi_v), axis=0)
        self.samples += t_s.size
        for i in range(len(AXES)):
            self._contacts(i, t_s, q_m[:, i])

    def _contacts(self, i: int, t_s: np.ndarray, q: np.ndarray) -> None:
        """Open, extend and close axis i's contacts over these samples."""
        upper, lower = q > self.upper_m[i], q < self.lower_m[i]
        inside = upper | lower
        was_inside = self._open[i] is not None
        if not was_inside and not inside.any():
            return
        change = np.flatnonzero(np.diff(np.concatenate(([was_inside], inside)).astype(np.int8)))
        bounds = [0, *change.tolist(), q.size]  # runs of equal ``inside``: [bounds[j], bounds[j+1])
        for a, b in zip(bounds[:-1], bounds[1:], strict=True):
            if a == b:
                continue
            if not inside[a]:
                if self._open[i] is not None:
                    self._open[i].left_s = float(t_s[a])
                    self._open[i] = None
                continue
            at_upper = bool(upper[a])
            furthest = float(q[a:b].max() if at_upper else q[a:b].min())
            contact = self._open[i]
            if contact is None:
                self.contacts[i] += 1
                end = float(self.ends_m[i, 1 if at_upper else 0])
                contact = EndStopEvent(float(t_s[a]), AXES[i], end, furthest)
                self._open[i] = contact
                if len(self.events[i]) < EVENTS_MAX:
                    self.events[i].append(contact)
            else:
                better = max if at_upper else min
                contact.position_m = better(contact.position_m, furthest)

    def summary(self) -> dict[str, Any]:
        """The summary.json fields ``events``, ``end_stop_contacts`` and ``saturation`` (docs/cli.md)."""
        events = sorted((e for axis in self.events for e in axis), key=lambda e: (e.t_s, e.axis))[:EVENTS_MAX]
        n = max(self.samples, 1)
        return {
            "events": [e.as_dict() for e in events],
            "end_stop_contacts": {axis: int(c) for axis, c in zip(AXES, self.contacts, strict=True)},
            "saturation": {
                axis: {"fraction": float(self.saturated[i]) / n, "limit_v": [float(v) for v in self.ctrl_range_v[i]]}
                for i, axis in enumerate(AXES)
            },
        }


def travel_summary(plant: Plant, trace: Trace) -> dict[str, Any]:
    """:meth:`TravelWatch.summary` of a finished trace (its ``filled`` samples)."""
    watch = TravelWatch(plant)
    for start in range(0, trace.filled, SCAN_BLOCK):
        stop = min(trace.filled, start + SCAN_BLOCK)
        watch.scan(trace.t_s[start:stop], trace.q_m[start:stop], trace.u_v[start:stop])
    return watch.summary()
