"""The rerun observer: logs one run, as it is simulated, to its own recording (rerun-sdk 0.41).

:class:`RerunObserver` is a :class:`gantry_twin.loop.trace.Observer`: it only reads the trace, and logs to its own
:class:`rerun.RecordingStream` (never the global one, so two runs in one process stay apart). Samples are
buffered and sent as columns (``send_columns``) at the end of a chunk, at most every ``flush_interval_s`` of
wall time; the 3D transforms, the XY contour and the estimates are decimated (the ``*_RATE_HZ`` constants).
Timeline ``sim_time`` (the trace's sample times); units are in the entity names.

(docs/telemetry.md, "What is recorded" and "Cost"; the layout: "The dashboard")
"""

from __future__ import annotations

import math
import os
import re
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import rerun as rr

from gantry_twin.gcode.part_error import distance_to_program
from gantry_twin.gcode.sampling import ProgramPath
from gantry_twin.loop.trace import RunInfo, Trace
from gantry_twin.paths.contours import reference
from gantry_twin.plant.model import THETA_NAMES, THETA_UNITS
from gantry_twin.telemetry.columns import TimeIndex, scalar_column
from gantry_twin.telemetry.dashboard import (
    ERROR_MAGNIFICATION,
    PROGRAM_ERROR_MAGNIFICATION,
    TIMELINE,
    VERDICTS_ENTITY,
    dashboard_blueprint,
    gantry_bodies,
    magnified_contour_m,
    panel_name,
    plot_range,
)
from gantry_twin.telemetry.sinks import check_grpc_url, require_display, spawn_native_viewer

#: Rate of the 3D transforms, Hz.
MARKER_RATE_HZ = 50.0
#: Rate of the points of the magnified actual contour, Hz.
CONTOUR_RATE_HZ = 1000.0
#: Rate of the parameter estimates theta^ and lambda_max(Gamma), Hz: they converge and drift over tens of
#: milliseconds to seconds, and they were nine of the eighteen 5 kHz series of a recording (sizes:
#: docs/performance.md, "Trace files"). dc^, the fast compensation, stays at the full rate.
ESTIMATE_RATE_HZ = 1000.0

_ESTIMATE_RGB = (230, 120, 30)
_TRUE_RGB = (120, 120, 120)
_X_RGB, _Y_RGB = (31, 119, 180), (214, 39, 40)
#: eps_c (true) is drawn wide in orange, eps_n (the approximation) thin in dark blue on top: both show where they meet.
_EPS_C_STYLE, _EPS_N_STYLE = ((230, 120, 30), 4.0), ((30, 30, 120), 1.0)
#: Margin of a plot's range when data leaves it (a larger step than the first range's, so it is re-sent rarely).
WIDEN_MARGIN = 0.25
#: A part program's part error (distance to the programmed lines and arcs), green; its programmed geometry, black.
_PART_STYLE, _PROGRAM_RGB, _RAPID_RGB = ((40, 160, 60), 1.5), (20, 20, 20), (170, 170, 170)
#: What an untrusted estimate's panel title and legend add: short, so that a narrow panel still shows it (the
#: reasons are in the verdicts panel).
DISTRUST_MARK = "not trusted"


def unit_in_entity(unit: str) -> str:
    """A unit as written in an entity path: ``V/(m/s^2)`` -> ``V_s2_per_m``, ``V/(m/s)`` -> ``V_s_per_m``."""
    quotient = re.fullmatch(r"(\w+)/\((\w+)/(\w+)(?:\^(\d+))?\)", unit)
    if quotient is None:
        return unit
    numerator, per, over, power = quotient.groups()
    return f"{numerator}_{over}{power or ''}_per_{per}"


def theta_entity(name: str) -> str:
    """Entity path of one parameter estimate, e.g. ``estimates/M1_V_s2_per_m`` (no unit if not in THETA_NAMES)."""
    if name not in THETA_NAMES:
        return f"estimates/{name}"
    return f"estimates/{name}_{unit_in_entity(THETA_UNITS[THETA_NAMES.index(name)])}"


# ---------------------------------------------------------------------------------------------
# The observer


class RerunObserver:
    """Logs one run to a rerun recording (docs/telemetry.md, "What is recorded").

    recording: a stream with its sinks already set (``rr.RecordingStream(...)``
    then ``.save``/``.spawn``/``.connect_grpc``, or ``set_sinks``); the
    constructors :meth:`to_file`, :meth:`spawn_viewer`, :meth:`connect` do that.
    error_magnification: K of the XY view (default :data:`ERROR_MAGNIFICATION`, for a part program's run
    :data:`PROGRAM_ERROR_MAGNIFICATION`); flush_interval_s: wall time between sends (0 = every chunk). One
    observer records one run.
    """

    def __init__(
        self,
        recording: rr.RecordingStream,
        *,
        error_magnification: float | None = None,
        flush_interval_s: float = 0.2,
        marker_rate_hz: float = MARKER_RATE_HZ,
        contour_rate_hz: float = CONTOUR_RATE_HZ,
        estimate_rate_hz: float = ESTIMATE_RATE_HZ,
    ) -> None:
        self.recording = recording
        self._monitor = None
        self._magnification_given = error_magnification
        self.error_magnification = float(ERROR_MAGNIFICATION if error_magnification is None else error_magnification)
        self.flush_interval_s = float(flush_interval_s)
        self.marker_rate_hz = float(marker_rate_hz)
        self.contour_rate_hz = float(contour_rate_hz)
        self.estimate_rate_hz = float(estimate_rate_hz)
        self._run: RunInfo | None = None

    def watch(self, monitor) -> None:  # noqa: ANN001 (a gantry_twin.health.monitor.MachineMonitor)
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
        recording.connect_grpc(spawn_native_viewer(recording))
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
        self._estimate_stride = max(1, int(round(1.0 / (self.estimate_rate_hz * ts))))
        self._sent = 0  # samples [0, _sent) are logged
        self._last_flush = -math.inf
        self._last_point_mm: np.ndarray | None = None
        self._estimates: list[tuple[str, int]] = []  # (entity, index into theta_hat)
        self._styled = False
        self._extents: dict[str, tuple[float, float]] = {}  # plot origin -> [min, max] of what it has had to show
        self._ranges: dict[str, tuple[float, float]] = {}  # plot origin -> the y range in the blueprint sent
        self._blueprint_sent = False
        self._verdicts = False  # mark_estimates has logged the verdicts
        self._bodies = gantry_bodies(run.plant)
        samples = run.samples or run.reference.t_s.size
        step = max(1, samples // 4000)
        times_s = np.append(np.arange(0, samples, step), samples - 1) * ts
        self._desired_mm = reference(run.path, run.timing, times_s).q_d * 1e3
        self._plan = run.path if isinstance(run.path, ProgramPath) else None  # a part program: its part error too
        if self._plan is not None and self._magnification_given is None:
            self.error_magnification = PROGRAM_ERROR_MAGNIFICATION
        self.recording.send_recording_name(f"{run.controller_name}, {run.duration_s:g} s")
        self._log_static_scene(run)

    def on_chunk(self, trace: Trace, start: int, stop: int) -> None:
        if not self._styled:
            self._log_static_styling(trace)
        now = time.perf_counter()
        if now - self._last_flush >= self.flush_interval_s or stop >= trace.first + trace.t_s.size:
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
        if self._plan is not None:  # the programmed lines and arcs (to scale), rapids apart
            table = self._plan.table
            for entity, rapid, colour, radius in (
                ("contour_mm/xy/programmed", False, _PROGRAM_RGB, -1.0),
                ("contour_mm/xy/rapids", True, _RAPID_RGB, -0.75),
            ):
                strips = [table.polyline(k) * 1e3 for k, m in enumerate(self._plan.moves) if m.rapid == rapid]
                if strips:
                    rec.log(entity, rr.LineStrips2D(strips, colors=[colour], radii=[radius]), static=True)

    @property
    def _actual_entity(self) -> str:
        return f"contour_mm/xy/actual_x{self.error_magnification:g}"

    def _log_static_styling(self, trace: Trace) -> None:
        """SeriesLines names and colours, once; and the blueprint (needs the controller's state keys)."""
        rec = self.recording
        self._styled = True

        def lines(
            entity: str, names: Sequence[str], colors: Sequence[tuple[int, int, int]], width: float | None = None
        ) -> None:
            widths = None if width is None else [width] * len(names)
            rec.log(entity, rr.SeriesLines(names=list(names), colors=list(colors), widths=widths), static=True)

        lines("errors/contour/eps_c_um", ["eps_c (true)"], [_EPS_C_STYLE[0]], _EPS_C_STYLE[1])
        lines("errors/contour/eps_n_um", ["eps_n (approx.)"], [_EPS_N_STYLE[0]], _EPS_N_STYLE[1])
        if self._plan is not None:
            lines("errors/contour/part_um", ["part error (to the program)"], [_PART_STYLE[0]], _PART_STYLE[1])
        lines("errors/axial/e_x_um", ["e_x"], [_X_RGB])
        lines("errors/axial/e_y_um", ["e_y"], [_Y_RGB])
        lines("inputs/u_x_V", ["u_x"], [_X_RGB])
        lines("inputs/u_y_V", ["u_y"], [_Y_RGB])
        lines("inputs/disturbance_x_V", ["d_x"], [(120, 180, 230)])
        lines("inputs/disturbance_y_V", ["d_y"], [(240, 140, 140)])
        state = trace.controller_state
        self._titles: dict[str, str] = {}
        theta = state.get("theta_hat")
        if theta is not None and theta.ndim == 2:
            names = (
                THETA_NAMES if theta.shape[1] == len(THETA_NAMES) else [f"theta{i + 1}" for i in range(theta.shape[1])]
            )
            for i, name in enumerate(names):
                entity = theta_entity(name)
                self._estimates.append((entity, i))
                if name in THETA_NAMES:
                    self._titles[entity] = panel_name(name, THETA_UNITS[THETA_NAMES.index(name)])
                lines(f"{entity}/estimate", [f"{name}^"], [_ESTIMATE_RGB])
                lines(f"{entity}/true", [f"{name} true"], [_TRUE_RGB])
        extra = []
        if "dc_hat" in state:
            lines("estimates/dc_hat_V", ["dc^_x", "dc^_y"], [_X_RGB, _Y_RGB])
            extra.append("estimates/dc_hat_V")
            self._titles["estimates/dc_hat_V"] = panel_name("dc^", "V")
        if "gamma_lambda_max" in state:
            lines("estimates/gamma_lambda_max", ["lambda_max(Gamma)"], [(60, 160, 60)])
            extra.append("estimates/gamma_lambda_max")
            self._titles["estimates/gamma_lambda_max"] = panel_name("lambda_max(Gamma)", "-")  # as in the paper
        self._plots = [e for e, _ in self._estimates] + extra

    def mark_estimates(self, distrust: dict[str, str]) -> None:
        """Mark each estimate whose name is a key of ``distrust`` (its reason, ``not trusted: why``, as
        summary.json judges it after the run): ``not trusted`` in its panel's title (before the unit, so a narrow
        panel still shows it) and in its legend; log the verdicts, each with its reason, as a text document
        (``estimates/verdicts``) and send the layout again with a panel for it. Call it after the run, before
        :meth:`close`."""
        if self._run is None or not self._styled:
            return
        for entity, i in self._estimates:
            name = THETA_NAMES[i] if i < len(THETA_NAMES) else f"theta{i + 1}"
            if name in distrust:
                unit = THETA_UNITS[i] if name in THETA_NAMES else "-"
                self._titles[entity] = panel_name(f"{name} {DISTRUST_MARK}", unit)
                self.recording.log(
                    f"{entity}/estimate",
                    rr.SeriesLines(names=[f"{name}^ ({DISTRUST_MARK})"], colors=[_ESTIMATE_RGB]),
                    static=True,
                )
        lines = [f"- **{name}**: {why}" for name, why in distrust.items()] or ["every estimate trusted"]
        self.recording.log(
            VERDICTS_ENTITY, rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN), static=True
        )
        self._verdicts = True
        self._send_blueprint()

    def _show(self, origin: str, *values: np.ndarray) -> None:
        """Widen plot ``origin``'s y range if ``values`` (finite ones) leave it (:meth:`_send` re-sends the layout)."""
        finite = [v[np.isfinite(v)] for v in (np.asarray(x, dtype=float).reshape(-1) for x in values)]
        finite = [v for v in finite if v.size]
        if not finite:
            return
        lo, hi = min(float(v.min()) for v in finite), max(float(v.max()) for v in finite)
        old = self._extents.get(origin)
        lo, hi = (lo, hi) if old is None else (min(lo, old[0]), max(hi, old[1]))
        self._extents[origin] = (lo, hi)
        shown = self._ranges.get(origin)
        if shown is None or lo < shown[0] or hi > shown[1]:
            self._ranges[origin] = plot_range(lo, hi) if shown is None else plot_range(lo, hi, WIDEN_MARGIN)

    def _send_blueprint(self) -> None:
        self.recording.send_blueprint(
            dashboard_blueprint(
                self._plots,
                self.error_magnification,
                self._desired_mm,
                health=self._monitor is not None,
                ranges=self._ranges,
                titles=self._titles,
                verdicts=self._verdicts,
            ),
            make_active=True,
            make_default=True,
        )
        self._blueprint_sent = True

    def _send(self, trace: Trace, start: int, stop: int) -> None:
        if stop <= start or self._run is None:
            return
        rec, rows, first = self.recording, trace.rows(start, stop), trace.first
        times = [TimeIndex(trace.t_s[rows])]

        def scalars(entity: str, values: np.ndarray, index: list = times) -> None:
            rec.send_columns(entity, indexes=index, columns=[scalar_column(values)])

        scalars("errors/contour/eps_c_um", trace.eps_c_m[rows] * 1e6)
        scalars("errors/contour/eps_n_um", trace.eps_n_m[rows] * 1e6)
        part_um = np.empty(0)
        feed = np.ones(stop - start, dtype=bool)  # the samples the error plots are ranged to
        if self._plan is not None:  # NaN during a rapid: a gap in the line
            t, q = trace.t_s[rows], trace.q_m[rows]
            moves = self._plan.sample(t).move
            part_um = distance_to_program(self._plan, moves, q) * 1e6
            scalars("errors/contour/part_um", part_um)
            feed = ~self._plan.rapid[moves]  # a rapid's error: drawn, off the scale
        scalars("errors/axial/e_x_um", trace.e_m[rows, 0] * 1e6)
        scalars("errors/axial/e_y_um", trace.e_m[rows, 1] * 1e6)
        scalars("inputs/u_x_V", trace.u_v[rows, 0])
        scalars("inputs/u_y_V", trace.u_v[rows, 1])
        scalars("inputs/disturbance_x_V", trace.disturbance_v[rows, 0])
        scalars("inputs/disturbance_y_V", trace.disturbance_v[rows, 1])
        ranges_before = dict(self._ranges)
        self._show("errors/contour", trace.eps_c_m[rows][feed] * 1e6, trace.eps_n_m[rows][feed] * 1e6, part_um)
        self._show("errors/axial", trace.e_m[rows][feed] * 1e6)
        self._show("inputs", trace.u_v[rows], trace.disturbance_v[rows])
        state = trace.controller_state
        k = self._estimate_stride
        slow = np.arange(-(-start // k) * k, stop, k) - first  # the samples at estimate_rate_hz
        slow_times = [TimeIndex(trace.t_s[slow])]
        if self._estimates:
            theta = state["theta_hat"][rows]  # every sample sets the plot's range; every k-th is logged
            if trace.true_theta_t is None:  # constant: a line needs two points per send
                at = np.array([start, stop - 1])
                true = np.broadcast_to(trace.true_theta, (2, trace.true_theta.size))
            else:  # plant changes move it: at the 3D marker rate, and the last sample
                at = np.unique(
                    np.append(
                        np.arange(-(-start // self._marker_stride) * self._marker_stride, stop, self._marker_stride),
                        stop - 1,
                    )
                )
                true = trace.true_theta_t[at - first]
            true_times = [TimeIndex(trace.t_s[at - first])]
            for entity, i in self._estimates:
                if slow.size:
                    scalars(f"{entity}/estimate", state["theta_hat"][slow, i], slow_times)
                if i < true.shape[1]:
                    scalars(f"{entity}/true", true[:, i], true_times)
                self._show(entity, theta[:, i], true[:, i] if i < true.shape[1] else ())
        if "dc_hat" in state:
            scalars("estimates/dc_hat_V", state["dc_hat"][rows])
            self._show("estimates/dc_hat_V", state["dc_hat"][rows])
        if "gamma_lambda_max" in state and slow.size:
            scalars("estimates/gamma_lambda_max", state["gamma_lambda_max"][slow], slow_times)
        if self._styled and (not self._blueprint_sent or self._ranges != ranges_before):
            self._send_blueprint()  # the first time, or data left a plot's range
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
            rec.send_columns("health/excitation_V", indexes=[TimeIndex(t)], columns=[scalar_column(level)])
            self._excitation_sent += t.size
            _, trusted = monitor.trusted_since(self._excitation_sent - t.size)
            if self._excitation_sent == t.size:
                rec.log("health/trustworthy", rr.SeriesLines(names=list(THETA_NAMES)), static=True)
            rec.send_columns("health/trustworthy", indexes=[TimeIndex(t)], columns=[scalar_column(trusted)])
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
        phi = run.timing.derivatives(trace.t_s[idx - trace.first])[0]  # the desired phi, as in the reference
        q = trace.q_m[idx - trace.first]
        factor = self.error_magnification
        if self._plan is not None:  # a rapid move is not part of the part: drawn where the machine is
            rapid = self._plan.rapid[self._plan.sample(trace.t_s[idx - trace.first]).move]
            factor = np.where(rapid, 1.0, factor)[:, None]
        points_mm = magnified_contour_m(run.path, q, phi, factor) * 1e3
        strip = points_mm if self._last_point_mm is None else np.vstack([self._last_point_mm, points_mm])
        self._last_point_mm = points_mm[-1:]
        rec.send_columns(
            self._actual_entity,
            indexes=[TimeIndex(trace.t_s[trace.rows(stop - 1, stop)])],
            columns=rr.LineStrips2D.columns(strips=[strip], colors=[_X_RGB], radii=[-1.5]),
        )
        # The moving bodies at marker_rate_hz.
        stride = self._marker_stride
        idx = np.arange(-(-start // stride) * stride, stop, stride)
        if idx.size == 0:
            return
        marker_times = [TimeIndex(trace.t_s[idx - trace.first])]
        q = trace.q_m[idx - trace.first]
        for body in self._bodies:
            if body.slides:
                rec.send_columns(
                    body.entity,
                    indexes=marker_times,
                    columns=rr.Transform3D.columns(translation=body.translations_m(q)),
                )
