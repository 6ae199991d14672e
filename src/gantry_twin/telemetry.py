"""Live rerun dashboard and recordings of a run (rerun-sdk 0.41).

:class:`RerunObserver` is a :class:`gantry_twin.simulate.Observer`: it only
reads the trace and logs it to its own :class:`rerun.RecordingStream` (never
the global one, so two runs in one process stay apart). Samples are buffered
and sent as columns (``send_columns``) at most every ``flush_interval_s`` of
wall time (default 0.2 s: five viewer updates a second), at the end of a
chunk; rerun's cost is mostly per row and per call (~100 ns a row, ~150 us a
call), so one send covers many chunks when the loop is fast. Static styling
is logged once; the 3D transforms (50 Hz) and the XY contour (1 kHz) are
decimated.

What is logged (timeline ``sim_time``, the trace's own sample times, exact to
the nanosecond; units in the entity names):

    errors/contour/eps_c_um, eps_n_um      true and approximate contour error, um
    errors/axial/e_x_um, e_y_um            axial tracking errors q - q_d, um
    inputs/u_x_V, u_y_V                    control command, volts
    inputs/disturbance_x_V, ..._y_V        input disturbance, volts
    estimates/<name>_<unit>/estimate       theta^_i, e.g. estimates/M1_V_s2_per_m/estimate
    estimates/<name>_<unit>/true           theta_i of the model (a line: its value at each send's ends)
    estimates/dc_hat_V                     [dc^_x, dc^_y]
    estimates/gamma_lambda_max             lambda_max(Gamma)
    contour_mm/xy/desired                  the desired contour (static), mm
    contour_mm/xy/actual_x<K>              the actual contour with its error magnified K times
    gantry/...                             base, carriages and payload as boxes (metres, 50 Hz)

Magnified contour: each actual point q is drawn at p + K (q - p), where p is
the closest point of the desired curve (``paths.contour_error``), so a contour
error of 1 um shows as K um; with the default K = 10 000, as 10 mm. (The
controllers hold eps_c near 1 um on the paper's 200 mm circle: at 1000x that
is under a pixel.)

Command line (wired into ``gantry-twin run`` by :func:`add_telemetry_arguments`
and :func:`telemetry_observers`) and Python::

    from gantry_twin.telemetry import RerunObserver
    with RerunObserver.to_file("run.rrd") as observer:   # or .spawn_viewer(), .connect(url)
        trace = simulate(..., observers=[observer])
"""

from __future__ import annotations

import argparse
import atexit
import math
import os
import socket
import subprocess
import sys
import tempfile
import time
import urllib.parse
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

import mujoco
import numpy as np
import pyarrow as pa
import rerun as rr
import rerun.blueprint as rrb

from gantry_twin.paths import contour_error
from gantry_twin.plant import THETA_NAMES, Plant
from gantry_twin.trace import Observer, RunInfo, Trace

#: Default magnification of the contour error in the XY view (1 um drawn as 1 mm).
ERROR_MAGNIFICATION = 10_000.0
#: Rate of the 3D transforms, Hz.
MARKER_RATE_HZ = 50.0
#: Rate of the points of the magnified actual contour, Hz.
CONTOUR_RATE_HZ = 1000.0
#: The timeline every sample is logged on (a duration from the start of the run).
TIMELINE = "sim_time"
#: Units of the entries of theta (paper section 2): M in V/(m/s^2), B in V/(m/s), Af and dN in V.
THETA_UNITS: dict[str, str] = {"M": "V_s2_per_m", "B": "V_s_per_m", "Af": "V", "dN": "V"}

_ESTIMATE_RGB = (230, 120, 30)
_TRUE_RGB = (120, 120, 120)
_X_RGB, _Y_RGB = (31, 119, 180), (214, 39, 40)


class TelemetryError(RuntimeError):
    """Telemetry cannot start; the message is one line, meant for the user."""


def theta_entity(name: str) -> str:
    """Entity path of one parameter estimate, e.g. ``estimates/M1_V_s2_per_m``."""
    unit = next((u for prefix, u in THETA_UNITS.items() if name.startswith(prefix)), None)
    return f"estimates/{name}_{unit}" if unit else f"estimates/{name}"


class _TimeIndex:
    """A ``sim_time`` column (rerun's TimeColumnLike) in whole nanoseconds, rounded rather than truncated.

    Built straight from the int64 buffer: ``rr.TimeColumn`` does the same through slower conversions.
    """

    def __init__(self, t_s: np.ndarray) -> None:
        self._times = pa.array(np.rint(np.asarray(t_s, dtype=float) * 1e9).astype(np.int64)).view(pa.duration("ns"))

    def timeline_name(self) -> str:
        return TIMELINE

    def as_arrow_array(self) -> pa.Array:
        return self._times


class _ArrowBatch:
    """A ready pyarrow array as a rerun ComponentBatchLike."""

    def __init__(self, array: pa.Array) -> None:
        self._array = array

    def as_arrow_array(self) -> pa.Array:
        return self._array


_SCALARS = rr.Scalars.descriptor_scalars()


def _scalar_column(values: np.ndarray) -> rr.ComponentColumn:
    """``Scalars`` column of N rows of k values from an (N,) or (N, k) array (= ``rr.Scalars.columns``, faster)."""
    values = np.asarray(values, dtype=np.float64)
    rows = values.shape[0]
    width = 1 if values.ndim == 1 else int(np.prod(values.shape[1:]))
    offsets = np.arange(0, rows * width + 1, width, dtype=np.int32)
    return rr.ComponentColumn(_SCALARS, _ArrowBatch(pa.array(values.reshape(-1))), offsets=offsets)


# ---------------------------------------------------------------------------------------------
# The gantry in 3D, read from the compiled MJCF model


@dataclass(frozen=True)
class BodyBoxes:
    """One body of the model drawn as its box geoms, in the body's own frame (metres).

    ``entity``: path under ``gantry/`` following the body tree. The body sits at
    ``offset_m`` (rotation ``quat_xyzw``) in its parent's frame, shifted by
    ``q[:, axis] * direction`` for each slide joint ``(axis, direction)``;
    ``axis`` indexes the trace's q (0 = X, 1 = Y).
    """

    entity: str
    offset_m: np.ndarray
    quat_xyzw: np.ndarray
    slides: tuple[tuple[int, np.ndarray], ...]
    half_sizes_m: np.ndarray
    centers_m: np.ndarray
    quats_xyzw: np.ndarray
    colors_rgba: np.ndarray

    def translations_m(self, q_m: np.ndarray) -> np.ndarray:
        """(N, 3) position of the body frame in its parent's frame for joint positions q (N, 2)."""
        q = np.atleast_2d(q_m)
        out = np.tile(self.offset_m, (q.shape[0], 1))
        for axis, direction in self.slides:
            out += q[:, axis : axis + 1] * direction
        return out


def _xyzw(quat_wxyz: np.ndarray) -> np.ndarray:
    w, x, y, z = np.asarray(quat_wxyz, dtype=float)
    return np.array([x, y, z, w])


def gantry_bodies(plant: Plant) -> list[BodyBoxes]:
    """Every body below the world that has box geoms or children, parents first."""
    m = plant.model
    axis_of_qpos = {int(adr): i for i, adr in enumerate(plant.qpos_index)}
    paths: dict[int, str] = {0: "gantry"}
    bodies: list[BodyBoxes] = []
    for b in range(1, m.nbody):
        name = m.body(b).name or f"body{b}"
        paths[b] = f"{paths[int(m.body_parentid[b])]}/{rr.escape_entity_path_part(name)}"
        rotation = np.zeros(9)
        mujoco.mju_quat2Mat(rotation, m.body_quat[b])
        slides = []
        for j in range(int(m.body_jntadr[b]), int(m.body_jntadr[b]) + int(m.body_jntnum[b])):
            if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_SLIDE and int(m.jnt_qposadr[j]) in axis_of_qpos:
                slides.append((axis_of_qpos[int(m.jnt_qposadr[j])], rotation.reshape(3, 3) @ m.jnt_axis[j]))
        geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] == b and m.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX]
        bodies.append(
            BodyBoxes(
                entity=paths[b],
                offset_m=m.body_pos[b].copy(),
                quat_xyzw=_xyzw(m.body_quat[b]),
                slides=tuple(slides),
                half_sizes_m=m.geom_size[geoms].copy(),
                centers_m=m.geom_pos[geoms].copy(),
                quats_xyzw=np.array([_xyzw(m.geom_quat[g]) for g in geoms]).reshape(-1, 4),
                colors_rgba=np.clip(np.rint(m.geom_rgba[geoms] * 255), 0, 255).astype(np.uint8),
            )
        )
    return bodies


def magnified_contour_m(path, q_m: np.ndarray, phi_guess: np.ndarray, factor: float) -> np.ndarray:
    """Points p + factor (q - p), p the closest point of ``path`` to each q (N, 2), metres."""
    _, phi_closest = contour_error(path, q_m, phi_guess)
    closest = path.derivatives(phi_closest)[0]
    return closest + factor * (np.asarray(q_m) - closest)


# ---------------------------------------------------------------------------------------------
# The dashboard


def dashboard_blueprint(
    estimate_entities: Sequence[str] = (),
    magnification: float = ERROR_MAGNIFICATION,
    desired_mm: np.ndarray | None = None,
    health: bool = False,
) -> rrb.Blueprint:
    """Default layout: contour and 3D | errors and inputs | one plot per estimate (if any).

    ``health``: add the health monitor's excitation plot and alarm log to the middle column.

    The XY view shows every strip of the actual contour up to the time cursor
    (visible range from -infinity); ``desired_mm`` (N, 2) sets its bounds.
    """
    history = rrb.VisibleTimeRange(
        TIMELINE, start=rr.TimeRangeBoundary.infinite(), end=rr.TimeRangeBoundary.cursor_relative()
    )
    bounds = None
    if desired_mm is not None and len(desired_mm):
        lo, hi = np.min(desired_mm, axis=0), np.max(desired_mm, axis=0)
        margin = 0.15 * float(np.max(hi - lo)) + 1.0
        # contour_mm/xy flips y (2D views draw y downwards), so the view's y range is mirrored.
        bounds = rrb.VisualBounds2D(
            x_range=[lo[0] - margin, hi[0] + margin], y_range=[-hi[1] - margin, -lo[1] + margin]
        )
    left = rrb.Vertical(
        rrb.Spatial2DView(
            origin="contour_mm",
            name=f"XY contour, mm (error x{magnification:g})",
            time_ranges=[history],
            visual_bounds=bounds,
        ),
        rrb.Spatial3DView(
            origin="gantry",
            name="Gantry (3D, m)",
            eye_controls=rrb.EyeControls3D(position=[0.9, -1.3, 0.9], look_target=[0.0, 0.0, -0.08]),
        ),
    )
    middle_views = [
        rrb.TimeSeriesView(origin="errors/contour", name="Contour error, um"),
        rrb.TimeSeriesView(origin="errors/axial", name="Axial errors, um"),
        rrb.TimeSeriesView(origin="inputs", name="Inputs, V"),
    ]
    if health:
        middle_views += [
            rrb.TimeSeriesView(origin="health/excitation_V", name="Excitation per axis, V"),
            rrb.TextLogView(origin="health/alarms", name="Health alarms"),
        ]
    middle = rrb.Vertical(*middle_views)
    columns: list = [left, middle]
    if estimate_entities:
        views = [rrb.TimeSeriesView(origin=e, name=e.removeprefix("estimates/")) for e in estimate_entities]
        columns.append(rrb.Grid(*views, grid_columns=2, name="Estimates"))
    shares = [1.0, 1.0, 1.2][: len(columns)]
    return rrb.Blueprint(
        rrb.Horizontal(*columns, column_shares=shares),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed"),
    )


# ---------------------------------------------------------------------------------------------
# The observer


class RerunObserver:
    """Logs one run to a rerun recording (see the module docstring for what and where).

    recording: a stream with its sinks already set (``rr.RecordingStream(...)``
    then ``.save``/``.spawn``/``.connect_grpc``, or ``set_sinks``); the
    constructors :meth:`to_file`, :meth:`spawn_viewer`, :meth:`connect` do that.
    error_magnification: K of the XY view; flush_interval_s: wall time between
    sends (0 = every chunk). One observer records one run.
    """

    def __init__(
        self,
        recording: rr.RecordingStream,
        *,
        error_magnification: float = ERROR_MAGNIFICATION,
        flush_interval_s: float = 0.2,
        marker_rate_hz: float = MARKER_RATE_HZ,
        contour_rate_hz: float = CONTOUR_RATE_HZ,
    ) -> None:
        self.recording = recording
        self._monitor = None
        self.error_magnification = float(error_magnification)
        self.flush_interval_s = float(flush_interval_s)
        self.marker_rate_hz = float(marker_rate_hz)
        self.contour_rate_hz = float(contour_rate_hz)
        self._run: RunInfo | None = None

    def watch(self, monitor) -> None:  # noqa: ANN001 (a gantry_twin.monitor.MachineMonitor)
        """Also log a health monitor's alarms (text events on the timeline, entity
        ``health/alarms``) and its excitation level per axis (``health/excitation_V``).
        The monitor must come before this observer in simulate's list."""
        self._monitor = monitor
        self._alarms_sent = 0
        self._excitation_sent = 0

    # -- constructors for the usual sinks ---------------------------------------------------

    @classmethod
    def to_file(cls, path: str | os.PathLike[str], application_id: str = "gantry_twin", **kwargs) -> RerunObserver:
        """Record into an .rrd file (open it later with ``rerun FILE.rrd``)."""
        recording = rr.RecordingStream(application_id)
        recording.save(Path(path))
        return cls(recording, **kwargs)

    @classmethod
    def spawn_viewer(cls, application_id: str = "gantry_twin", **kwargs) -> RerunObserver:
        """Start (or reuse) a native viewer on this machine and stream to it."""
        require_display()
        recording = rr.RecordingStream(application_id)
        recording.connect_grpc(_spawn_native_viewer(recording))
        return cls(recording, **kwargs)

    @classmethod
    def connect(cls, url: str, application_id: str = "gantry_twin", **kwargs) -> RerunObserver:
        """Stream to a viewer or server already running at ``url`` (rerun+http://HOST:PORT/proxy)."""
        recording = rr.RecordingStream(application_id)
        recording.connect_grpc(check_grpc_url(url))
        return cls(recording, **kwargs)

    # -- Observer protocol ------------------------------------------------------------------

    def on_start(self, run: RunInfo, trace: Trace) -> None:
        if self._run is not None:
            raise RuntimeError("a RerunObserver records one run; create a new one for each run")
        self._run = run
        ts = trace.sample_period_s or run.plant.timestep_s
        self._marker_stride = max(1, int(round(1.0 / (self.marker_rate_hz * ts))))
        self._contour_stride = max(1, int(round(1.0 / (self.contour_rate_hz * ts))))
        self._sent = 0  # samples [0, _sent) are logged
        self._last_flush = -math.inf
        self._last_point_mm: np.ndarray | None = None
        self._estimates: list[tuple[str, int]] = []  # (entity, index into theta_hat)
        self._styled = False
        self._bodies = gantry_bodies(run.plant)
        step = max(1, run.reference.q_d.shape[0] // 4000)
        self._desired_mm = np.vstack([run.reference.q_d[::step], run.reference.q_d[-1:]]) * 1e3
        self.recording.send_recording_name(f"{run.controller_name}, {run.duration_s:g} s")
        self._log_static_scene(run)

    def on_chunk(self, trace: Trace, start: int, stop: int) -> None:
        if not self._styled:
            self._log_static_styling(trace)
        now = time.perf_counter()
        if now - self._last_flush >= self.flush_interval_s:
            self._send(trace, self._sent, trace.filled)
            self._last_flush = now

    def on_end(self, trace: Trace) -> None:
        if not self._styled:
            self._log_static_styling(trace)
        self._send(trace, self._sent, trace.filled)
        self.recording.flush(timeout_sec=0.0)  # start pushing the tail out; close() waits for it

    def close(self, timeout_s: float = 30.0) -> None:
        """Flush and detach the sinks (files are complete after this).

        A viewer that does not take the data within ``timeout_s`` is given up on
        with a warning on stderr rather than blocking the program.
        """
        try:
            self.recording.flush(timeout_sec=timeout_s)
        except Exception as error:  # rerun raises a bare RuntimeError-like error on timeout
            print(
                f"warning: telemetry: not all data reached the viewer within {timeout_s:g} s ({error})", file=sys.stderr
            )
        self.recording.disconnect()

    def __enter__(self) -> RerunObserver:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()

    # -- logging ---------------------------------------------------------------------------

    def _log_static_scene(self, run: RunInfo) -> None:
        rec = self.recording
        rec.log("gantry", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for body in self._bodies:
            # Static data shadows temporal data of the same component: a moving body gets its
            # translation only from the 50 Hz columns.
            if body.slides:
                rec.log(body.entity, rr.Transform3D(quaternion=body.quat_xyzw), static=True)
            else:
                rec.log(body.entity, rr.Transform3D(translation=body.offset_m, quaternion=body.quat_xyzw), static=True)
            if body.half_sizes_m.size:
                rec.log(
                    body.entity,
                    rr.Boxes3D(
                        half_sizes=body.half_sizes_m,
                        centers=body.centers_m,
                        quaternions=body.quats_xyzw,
                        colors=body.colors_rgba,
                        fill_mode="solid",
                    ),
                    static=True,
                )
        # rerun's 2D views draw y downwards; flip so +y points up as on the machine.
        rec.log("contour_mm/xy", rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
        rec.log(
            "contour_mm/xy/desired", rr.LineStrips2D([self._desired_mm], colors=[_TRUE_RGB], radii=[-1.5]), static=True
        )

    @property
    def _actual_entity(self) -> str:
        return f"contour_mm/xy/actual_x{self.error_magnification:g}"

    def _log_static_styling(self, trace: Trace) -> None:
        """SeriesLines names and colours, once; and the blueprint (needs the controller's state keys)."""
        rec = self.recording
        self._styled = True

        def lines(entity: str, names: Sequence[str], colors: Sequence[tuple[int, int, int]]) -> None:
            rec.log(entity, rr.SeriesLines(names=list(names), colors=list(colors)), static=True)

        lines("errors/contour/eps_c_um", ["eps_c (true)"], [_ESTIMATE_RGB])
        lines("errors/contour/eps_n_um", ["eps_n (approx.)"], [_X_RGB])
        lines("errors/axial/e_x_um", ["e_x"], [_X_RGB])
        lines("errors/axial/e_y_um", ["e_y"], [_Y_RGB])
        lines("inputs/u_x_V", ["u_x"], [_X_RGB])
        lines("inputs/u_y_V", ["u_y"], [_Y_RGB])
        lines("inputs/disturbance_x_V", ["d_x"], [(120, 180, 230)])
        lines("inputs/disturbance_y_V", ["d_y"], [(240, 140, 140)])
        state = trace.controller_state
        theta = state.get("theta_hat")
        if theta is not None and theta.ndim == 2:
            names = (
                THETA_NAMES if theta.shape[1] == len(THETA_NAMES) else [f"theta{i + 1}" for i in range(theta.shape[1])]
            )
            for i, name in enumerate(names):
                entity = theta_entity(name)
                self._estimates.append((entity, i))
                lines(f"{entity}/estimate", [f"{name}^"], [_ESTIMATE_RGB])
                lines(f"{entity}/true", [f"{name} true"], [_TRUE_RGB])
        extra = []
        if "dc_hat" in state:
            lines("estimates/dc_hat_V", ["dc^_x", "dc^_y"], [_X_RGB, _Y_RGB])
            extra.append("estimates/dc_hat_V")
        if "gamma_lambda_max" in state:
            lines("estimates/gamma_lambda_max", ["lambda_max(Gamma)"], [(60, 160, 60)])
            extra.append("estimates/gamma_lambda_max")
        rec.send_blueprint(
            dashboard_blueprint(
                [e for e, _ in self._estimates] + extra,
                self.error_magnification,
                self._desired_mm,
                health=self._monitor is not None,
            ),
            make_active=True,
            make_default=True,
        )

    def _send(self, trace: Trace, start: int, stop: int) -> None:
        if stop <= start or self._run is None:
            return
        rec = self.recording
        times = [_TimeIndex(trace.t_s[start:stop])]

        def scalars(entity: str, values: np.ndarray, index: list = times) -> None:
            rec.send_columns(entity, indexes=index, columns=[_scalar_column(values)])

        scalars("errors/contour/eps_c_um", trace.eps_c_m[start:stop] * 1e6)
        scalars("errors/contour/eps_n_um", trace.eps_n_m[start:stop] * 1e6)
        scalars("errors/axial/e_x_um", trace.e_m[start:stop, 0] * 1e6)
        scalars("errors/axial/e_y_um", trace.e_m[start:stop, 1] * 1e6)
        scalars("inputs/u_x_V", trace.u_v[start:stop, 0])
        scalars("inputs/u_y_V", trace.u_v[start:stop, 1])
        scalars("inputs/disturbance_x_V", trace.disturbance_v[start:stop, 0])
        scalars("inputs/disturbance_y_V", trace.disturbance_v[start:stop, 1])
        state = trace.controller_state
        if self._estimates:
            theta = state["theta_hat"][start:stop]
            if trace.true_theta_t is None:  # constant: a line needs two points per send
                rows = np.array([start, stop - 1])
                true = np.broadcast_to(trace.true_theta, (2, trace.true_theta.size))
            else:  # plant changes move it: at the 3D marker rate, and the last sample
                rows = np.unique(np.append(np.arange(-(-start // self._marker_stride) * self._marker_stride, stop,
                                                     self._marker_stride), stop - 1))
                true = trace.true_theta_t[rows]
            true_times = [_TimeIndex(trace.t_s[rows])]
            for entity, i in self._estimates:
                scalars(f"{entity}/estimate", theta[:, i])
                if i < true.shape[1]:
                    scalars(f"{entity}/true", true[:, i], true_times)
        if "dc_hat" in state:
            scalars("estimates/dc_hat_V", state["dc_hat"][start:stop])
        if "gamma_lambda_max" in state:
            scalars("estimates/gamma_lambda_max", state["gamma_lambda_max"][start:stop])
        self._send_geometry(trace, start, stop)
        self._send_health()
        self._sent = stop

    def _send_health(self) -> None:
        monitor = self._monitor
        if monitor is None:
            return
        rec = self.recording
        t, level = monitor.excitation_since(self._excitation_sent)
        if t.size:
            if self._excitation_sent == 0:
                rec.log("health/excitation_V", rr.SeriesLines(names=["x", "y"], colors=[_X_RGB, _Y_RGB]), static=True)
            rec.send_columns("health/excitation_V", indexes=[_TimeIndex(t)], columns=[_scalar_column(level)])
            self._excitation_sent += t.size
        alarms = monitor.alarms
        for alarm in alarms[self._alarms_sent :]:
            rec.set_time(TIMELINE, duration=alarm.time_s)
            rec.log("health/alarms", rr.TextLog(f"ALARM {alarm.describe()}", level=rr.TextLogLevel.WARN))
        if len(alarms) > self._alarms_sent:
            rec.reset_time()
        self._alarms_sent = len(alarms)

    def _send_geometry(self, trace: Trace, start: int, stop: int) -> None:
        rec, run = self.recording, self._run
        assert run is not None
        # Magnified actual contour: one strip per send, joined to the previous one.
        stride = self._contour_stride
        idx = np.arange(-(-start // stride) * stride, stop, stride)
        if idx.size == 0 or idx[-1] != stop - 1:
            idx = np.append(idx, stop - 1)
        points_mm = magnified_contour_m(run.path, trace.q_m[idx], run.reference.phi[idx], self.error_magnification)
        points_mm *= 1e3
        strip = points_mm if self._last_point_mm is None else np.vstack([self._last_point_mm, points_mm])
        self._last_point_mm = points_mm[-1:]
        rec.send_columns(
            self._actual_entity,
            indexes=[_TimeIndex(trace.t_s[stop - 1 : stop])],
            columns=rr.LineStrips2D.columns(strips=[strip], colors=[_X_RGB], radii=[-1.5]),
        )
        # The moving bodies at marker_rate_hz.
        stride = self._marker_stride
        idx = np.arange(-(-start // stride) * stride, stop, stride)
        if idx.size == 0:
            return
        marker_times = [_TimeIndex(trace.t_s[idx])]
        q = trace.q_m[idx]
        for body in self._bodies:
            if body.slides:
                rec.send_columns(
                    body.entity,
                    indexes=marker_times,
                    columns=rr.Transform3D.columns(translation=body.translations_m(q)),
                )


# ---------------------------------------------------------------------------------------------
# Pacing


class RealtimePacer:
    """Sleeps after each chunk so that simulated time / wall time = ``factor`` (1 = real time)."""

    def __init__(self, factor: float = 1.0) -> None:
        if not (math.isfinite(factor) and factor > 0):
            raise ValueError(f"realtime factor must be a number > 0, got {factor!r}")
        self.factor = float(factor)

    def on_start(self, run: RunInfo, trace: Trace) -> None:
        self._t0 = time.perf_counter()
        self._ts = trace.sample_period_s or run.plant.timestep_s

    def on_chunk(self, trace: Trace, start: int, stop: int) -> None:
        due = self._t0 + stop * self._ts / self.factor
        delay = due - time.perf_counter()
        if delay > 0:
            time.sleep(delay)

    def on_end(self, trace: Trace) -> None:
        pass


# ---------------------------------------------------------------------------------------------
# Sinks: display check, URL check, the local web viewer


def has_display() -> bool:
    """True where a native viewer window can open (Linux/BSD: $DISPLAY or $WAYLAND_DISPLAY set)."""
    if not sys.platform.startswith(("linux", "freebsd", "openbsd", "netbsd")):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def require_display() -> None:
    if not has_display():
        raise TelemetryError(
            "--viewer: no display here ($DISPLAY and $WAYLAND_DISPLAY are unset); "
            "use --serve-web and open the printed URL in a browser, or --save FILE.rrd"
        )


def _spawn_native_viewer(recording: rr.RecordingStream) -> str:
    """Start the native viewer on a free local port (blocks until it listens); its gRPC URL."""
    port = _free_port()
    rr.spawn(port=port, connect=False, hide_welcome_screen=True, executable_path=rerun_binary(), recording=recording)
    return f"rerun+http://127.0.0.1:{port}/proxy"


def check_grpc_url(url: str) -> str:
    parsed = urllib.parse.urlparse(url)
    if parsed.scheme not in ("rerun", "rerun+http", "rerun+https") or not parsed.netloc:
        raise TelemetryError(f"--connect: URL must look like rerun+http://HOST:PORT/proxy, got {url!r}")
    return url


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_for_port(port: int, process: subprocess.Popen, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if process.poll() is not None:
            return False
        with socket.socket() as s:
            s.settimeout(0.2)
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return True
        time.sleep(0.05)
    return False


def rerun_binary() -> str:
    """The rerun viewer/server binary shipped with rerun-sdk (not the Python wrapper, which would
    leave the binary running when terminated)."""
    if "RERUN_CLI_PATH" in os.environ:
        return os.environ["RERUN_CLI_PATH"]
    import rerun_cli

    folder = Path(rerun_cli.__file__).parent
    candidates = [folder / "Rerun.app" / "Contents" / "MacOS" / "Rerun", folder / "rerun", folder / "rerun.exe"]
    for candidate in candidates:
        if candidate.is_file():
            return str(candidate)
    raise TelemetryError(f"the rerun binary is missing from {folder} (reinstall rerun-sdk)")


class WebViewerServer:
    """rerun's web viewer and gRPC server in a child process, bound to 127.0.0.1 only."""

    def __init__(self, grpc_port: int | None = None, web_port: int | None = None, timeout_s: float = 20.0) -> None:
        self.grpc_port = grpc_port or _free_port()
        self.web_port = web_port or _free_port()
        self.grpc_url = f"rerun+http://127.0.0.1:{self.grpc_port}/proxy"
        query = urllib.parse.urlencode({"url": self.grpc_url})
        self.url = f"http://127.0.0.1:{self.web_port}/?{query}"
        command = [rerun_binary(), "--serve-web", "--bind", "127.0.0.1"]
        command += ["--port", str(self.grpc_port), "--web-viewer-port", str(self.web_port)]
        self._log = tempfile.TemporaryFile(mode="w+")
        self.process = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=self._log, stderr=self._log)
        atexit.register(self.stop)
        if not (
            _wait_for_port(self.grpc_port, self.process, timeout_s)
            and _wait_for_port(self.web_port, self.process, timeout_s)
        ):
            self.stop()
            self._log.seek(0)
            last = next((line.strip() for line in reversed(self._log.read().splitlines()) if line.strip()), "")
            raise TelemetryError(f"--serve-web: the rerun web viewer did not start ({last or 'no output'})")

    def stop(self) -> None:
        """Stop the server process (idempotent)."""
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        atexit.unregister(self.stop)


# ---------------------------------------------------------------------------------------------
# Command line


def _realtime_factor(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"FACTOR must be a number > 0 (1 = real time), got {text!r}")
    return value


def add_telemetry_arguments(parser: argparse.ArgumentParser) -> None:
    """Add --viewer, --save, --connect, --serve-web and --realtime (default: no telemetry, unpaced)."""
    group = parser.add_argument_group("telemetry (rerun)")
    group.add_argument("--viewer", action="store_true", help="spawn the rerun viewer and stream the run to it")
    group.add_argument("--save", metavar="FILE.rrd", type=Path, help="record the run; open later with `rerun FILE.rrd`")
    group.add_argument(
        "--connect", metavar="URL", help="stream to a running viewer, e.g. rerun+http://127.0.0.1:9876/proxy"
    )
    group.add_argument(
        "--serve-web", action="store_true", help="serve the web viewer on 127.0.0.1 (prints the URL; Ctrl-C stops)"
    )
    group.add_argument(
        "--realtime",
        metavar="FACTOR",
        nargs="?",
        const=1.0,
        default=None,
        type=_realtime_factor,
        help="pace the run to the wall clock: sim time / wall time = FACTOR (default 1)",
    )


class TelemetryObservers(list):
    """The observers for a run plus what they hold open; a list and a context manager.

    ``close()`` flushes every recording; with --serve-web it then keeps serving
    until Ctrl-C (``wait=True``) and stops the server.
    """

    def __init__(
        self,
        observers: Sequence[Observer],
        rerun_observer: RerunObserver | None,
        server: WebViewerServer | None,
        out: TextIO,
    ) -> None:
        super().__init__(observers)
        self.rerun_observer = rerun_observer
        self.server = server
        self.out = out

    @property
    def url(self) -> str | None:
        """The web viewer's URL with --serve-web, else None."""
        return self.server.url if self.server else None

    def close(self, wait: bool = True) -> None:
        try:
            if self.rerun_observer is not None:
                self.rerun_observer.close()
            if self.server is not None and wait:
                try:  # from before the message: Ctrl-C may come as soon as it is printed
                    print(f"Still serving the viewer at {self.server.url} ; press Ctrl-C to stop.", file=self.out)
                    self.out.flush()
                    while self.server.process.poll() is None:
                        time.sleep(0.2)
                except KeyboardInterrupt:
                    pass
        finally:
            if self.server is not None:
                self.server.stop()

    def __enter__(self) -> TelemetryObservers:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(wait=exc_type is None)


def telemetry_observers(
    args: argparse.Namespace, *, application_id: str = "gantry_twin", out: TextIO | None = None
) -> TelemetryObservers:
    """Observers for the telemetry options in ``args`` (empty: no telemetry).

    Checks every option before opening anything (TelemetryError, one line).
    Use as ``with telemetry_observers(args) as observers: simulate(..., observers=observers)``.
    """
    out = out or sys.stdout
    save: Path | None = getattr(args, "save", None)
    connect: str | None = getattr(args, "connect", None)
    viewer = bool(getattr(args, "viewer", False))
    serve_web = bool(getattr(args, "serve_web", False))
    realtime: float | None = getattr(args, "realtime", None)
    if save is not None:
        save = Path(save)
        if save.suffix != ".rrd":
            raise TelemetryError(f"--save: FILE must end in .rrd, got {str(save)!r}")
        if not save.parent.is_dir():
            raise TelemetryError(f"--save: directory {str(save.parent)!r} does not exist")
    if connect is not None:
        check_grpc_url(connect)
    if viewer:
        require_display()
    observers: list[Observer] = []
    rerun_observer = None
    server = None
    if save or connect or viewer or serve_web:
        sinks: list = []
        if serve_web:
            server = WebViewerServer()
            sinks.append(rr.GrpcSink(server.grpc_url))
            print(f"Rerun web viewer: {server.url}", file=out, flush=True)
        recording = rr.RecordingStream(application_id)
        if viewer:
            sinks.append(rr.GrpcSink(_spawn_native_viewer(recording)))
        if connect:
            sinks.append(rr.GrpcSink(connect))
        try:
            if save:
                sinks.append(rr.FileSink(save))
            recording.set_sinks(*sinks)
        except (RuntimeError, OSError) as error:
            if server is not None:
                server.stop()
            raise TelemetryError(f"--save: cannot write {str(save)!r}: {error}") from None
        rerun_observer = RerunObserver(recording)
        observers.append(rerun_observer)
    if realtime is not None:
        observers.append(RealtimePacer(realtime))
    return TelemetryObservers(observers, rerun_observer, server, out)


def main(argv: Sequence[str] | None = None) -> int:
    """A short demo run with telemetry: ``python -m gantry_twin.telemetry --serve-web``."""
    from gantry_twin import Payload, TimingLaw, circle, simulate
    from gantry_twin.controllers import create

    parser = argparse.ArgumentParser(prog="python -m gantry_twin.telemetry", description=main.__doc__)
    parser.add_argument("--duration", type=float, default=2.0, metavar="SECONDS", help="simulated time (default 2)")
    parser.add_argument("--controller", default="diarc", help="controller name (default diarc)")
    add_telemetry_arguments(parser)
    args = parser.parse_args(argv)
    try:
        observers = telemetry_observers(args)
    except TelemetryError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    try:
        with observers:
            simulate(
                Plant(Payload(5.0)),
                circle(),
                TimingLaw(2.0),
                create(args.controller),
                duration_s=args.duration,
                observers=observers,
                controller_name=args.controller,
            )
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
