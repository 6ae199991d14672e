"""What a run leaves behind: summary.json, the trace as Parquet, atomic writes.

``summary.json`` is a stable contract (docs/cli.md): a pure function of the
resolved scenario and the code, so the same scenario run twice gives the
same bytes. The wall-clock time is the only thing that differs between two
runs, so it lives in ``run_info.json`` beside it.

Every file is written atomically: into a temporary file in the same
directory, flushed and fsync'ed, then renamed over the final name
(``os.replace``). A crash leaves either the old file, the new file, or a
hidden ``.<name>.*.part`` file, never a half-written file under the final
name; an exception (Ctrl-C, and SIGTERM and SIGHUP under the command line)
removes the temporary file. The trace can be written as the run goes
(:class:`TraceWriter`, one Parquet row group per piece of the run).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from gantry_twin.metrics import RunMetrics, WholeRunMetrics, estimate_errors_pct
from gantry_twin.plant import AXES, THETA_NAMES
from gantry_twin.scenario import Scenario
from gantry_twin.trace import RunInfo, Trace

#: Version of the summary.json layout; bumped on any incompatible change.
SUMMARY_SCHEMA_VERSION = 1


#: Signals the command line turns into an exception (cli.py); held while a temporary file is being created.
STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """Delay SIGINT, SIGTERM and SIGHUP until the block ends (where the platform allows)."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def temporary_file(path: Path) -> tuple[IO[bytes], Path]:
    """A new hidden ``.<name>.*.part`` file beside ``path`` (with the usual permissions), open for writing.

    Create and name it inside ``with signals_held():`` within the ``try``
    whose ``except`` discards it, so that an interrupt comes after the name is known.
    """
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".part")
    try:
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        return os.fdopen(fd, "wb"), Path(tmp)
    except BaseException:
        os.close(fd)
        os.unlink(tmp)
        raise


def commit(fh: IO[bytes], tmp: Path, path: Path) -> None:
    """Flush, fsync and close ``fh`` (the temporary file ``tmp``), rename it to ``path``, fsync the directory."""
    fh.flush()
    os.fsync(fh.fileno())
    fh.close()
    os.replace(tmp, path)
    _fsync_dir(path.parent)


def discard(fh: IO[bytes] | None, tmp: Path | None) -> None:
    """Close and remove a temporary file (whatever state it is in)."""
    if fh is not None:
        with contextlib.suppress(OSError):
            fh.close()
    if tmp is not None:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)


def atomic_write(path: Path, write: Callable[[IO[bytes]], None]) -> None:
    """Write a file via temp file + fsync + os.replace; on error no file appears."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fh = tmp = None
    try:
        with signals_held():
            fh, tmp = temporary_file(path)
        write(fh)
        commit(fh, tmp, path)
    except BaseException:
        discard(fh, tmp)
        raise


def remove_tree(path: Path) -> None:
    """Remove a directory and what it holds, if it exists."""
    import shutil

    shutil.rmtree(path, ignore_errors=True)


def atomic_write_dir(path: Path, write: Callable[[Path], None]) -> None:
    """Fill a directory via a hidden ``.<name>.*.part`` directory beside it renamed to ``path`` (an earlier
    ``path`` is removed first); on error no directory appears."""
    path = Path(path)
    tmp = None
    try:
        with signals_held():
            tmp = Path(tempfile.mkdtemp(dir=path.parent, prefix=f".{path.name}.", suffix=".part"))
        os.chmod(tmp, 0o777 & ~_umask())
        write(tmp)
        remove_tree(path)
        os.replace(tmp, path)
        _fsync_dir(path.parent)
    except BaseException:
        if tmp is not None:
            remove_tree(tmp)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write(path, lambda fh: fh.write(text.encode("utf-8")))


def _fsync_dir(directory: Path) -> None:
    """Make the rename durable (POSIX; a no-op where directories cannot be opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def summary(scenario: Scenario, trace: Trace, controller_name: str, health: Any = None) -> dict[str, Any]:
    """The summary.json contract (see docs/cli.md) of a run's whole trace; deterministic for a given scenario.

    health: the run's :class:`gantry_twin.monitor.MonitorReport` (a ``health``
    section is added only when given). Estimates are judged against the mean
    true theta over the same window (it moves when the scenario has changes).
    """
    metrics = RunMetrics.for_scenario(scenario)
    metrics.on_chunk(trace, trace.first, trace.filled)
    return run_summary(scenario, controller_name, trace.sample_period_s, trace.filled, metrics, health)


@dataclass(frozen=True)
class Failure:
    """Why a run stopped before its end: at time_s, sample ``step`` (None if before the first), the error text."""

    time_s: float | None
    step: int | None
    error: str


def run_summary(
    scenario: Scenario,
    controller_name: str,
    sample_period_s: float,
    steps: int,
    metrics: RunMetrics,
    health: Any = None,
    failure: Failure | None = None,
    overrides: Sequence[str] = (),
    controller_option: str | None = None,
) -> dict[str, Any]:
    """:func:`summary` from what the run's observers gathered; ``failure``: the run stopped early (status failed,
    no contour error or estimates: they judge a whole run). ``overrides``, ``controller_option``: the command
    line's ``--set KEY=VALUE`` and ``--controller`` (already in the resolved scenario; kept to say how it was made)."""
    out: dict[str, Any] = {
        "schema_version": SUMMARY_SCHEMA_VERSION,
        "scenario": scenario.name,
        "controller": controller_name,
        "overrides": list(overrides),
        "controller_option": controller_option,
        "duration_s": scenario.duration_s,
        "sample_period_s": sample_period_s,
        "steps": int(steps),
        "status": "ok" if failure is None else "failed",
    }
    if failure is not None:
        out["failure"] = {"time_s": failure.time_s, "step": failure.step, "error": failure.error}
    else:
        contour = metrics.contour()
        out["contour_error_um"] = {"rms": contour.rms_um, "max": contour.max_um, "window_s": list(contour.window_s)}
        whole = metrics.whole_run()
        if whole is not None:
            out.update(whole_run_summary(whole))
        estimates = metrics.estimates()
        if estimates is not None and estimates[0].shape == (len(THETA_NAMES),):  # a plug-in may log another
            estimate, true = estimates
            errors = estimate_errors_pct(estimate, true)
            out["estimates_window_s"] = list(scenario.estimate_window_s)
            out["estimates"] = {
                name: {"estimate": float(est), "true": float(tru), "error_pct": errors[name]}
                for name, est, tru in zip(THETA_NAMES, estimate, true, strict=True)
            }
            if metrics.confidence is not None:  # trustworthy, why, excitation_v, bias_bound_pct (docs/cli.md)
                for name, verdict in metrics.confidence.verdicts(estimate).items():
                    out["estimates"][name].update(verdict)
                out["confidence"] = metrics.confidence.statistics()
    if health is not None:
        out["health"] = health_summary(health)
    return out


def whole_run_summary(whole: WholeRunMetrics) -> dict[str, Any]:
    """The ``whole_run`` and ``contour_error_per_period_um`` sections (docs/cli.md)."""
    return {
        "whole_run": {
            "window_s": list(whole.window_s),
            "contour_error_um": {"rms": whole.contour_rms_um, "max": whole.contour_max_um},
            "axial_error_rms_um": dict(zip(AXES, whole.axial_rms_um, strict=True)),
            "command_window_s": list(whole.command_window_s),
            "max_abs_command_v": dict(zip(AXES, whole.max_abs_command_v, strict=True)),
        },
        "contour_error_per_period_um": {
            "start_s": whole.periods_start_s,
            "period_s": whole.period_s,
            "rms": list(whole.period_rms_um),
        },
    }


#: The printed summary lists the rms of each period when the run has at most this many (else the first and last).
PERIODS_PRINTED = 12


def whole_run_lines(data: dict[str, Any]) -> list[str]:
    """The printed lines of summary.json's whole-run figures, each with its window (none for an older summary)."""
    whole, periods = data.get("whole_run"), data.get("contour_error_per_period_um")
    lines = []
    if whole is not None:
        (a, b), (ca, cb) = whole["window_s"], whole["command_window_s"]
        c, e, u = whole["contour_error_um"], whole["axial_error_rms_um"], whole["max_abs_command_v"]
        lines += [
            f"contour error eps_c over [{a:.3f}, {b:.3f}] s (whole run from the start of window_s): "
            f"rms {c['rms']:.3f} um, max {c['max']:.3f} um",
            f"axial error e over [{a:.3f}, {b:.3f}] s: rms " + ", ".join(f"{k} {v:.3f} um" for k, v in e.items()),
            f"command u over [{ca:.3f}, {cb:.3f}] s: max |u| " + ", ".join(f"{k} {v:.3f} V" for k, v in u.items()),
        ]
        saturation = data.get("saturation")
        if saturation:
            lines[-1] += "; at the limit " + ", ".join(
                f"{k} {100 * s['fraction']:.2f} %" for k, s in saturation.items()
            )
    if periods is not None and periods["rms"]:
        rms = periods["rms"]
        shown = " ".join(f"{v:.3f}" for v in rms)
        if len(rms) > PERIODS_PRINTED:
            half = PERIODS_PRINTED // 2
            shown = " ".join(f"{v:.3f}" for v in rms[:half]) + " ... " + " ".join(f"{v:.3f}" for v in rms[-half:])
        lines.append(
            f"rms eps_c per period of {periods['period_s']:.3f} s from {periods['start_s']:.3f} s "
            f"({len(rms)} period{'' if len(rms) == 1 else 's'}, the last up to the end): {shown} um"
        )
    return lines


def health_summary(report: Any) -> dict[str, Any]:
    """The ``health`` section: alarms, status per parameter, excitation per axis (docs/health.md)."""
    period = float(report.t_s[1] - report.t_s[0]) if report.t_s.size > 1 else 0.0
    alarms = [
        {
            "parameter": a.parameter,
            "time_s": a.time_s,
            "direction": a.direction,
            "change_pct": a.change_pct,
            "change": a.change,
            "unit": a.unit,
            "estimate": a.estimate,
            "baseline": a.baseline,
            "cleared_s": a.cleared_s,
        }
        for a in report.alarms
    ]
    excitation = {}
    for i, axis in enumerate(AXES):
        level = report.level_v[:, i] if report.level_v.size else np.zeros(0)
        excitation[axis] = {
            "level_v_final": float(level[-1]) if level.size else None,
            "level_v_min": float(level.min()) if level.size else None,
            "excited_fraction": float(report.excited[:, [j for j in range(8) if j % 2 == i]].all(axis=1).mean())
            if level.size
            else 0.0,
        }
    out: dict[str, Any] = {
        "alarms": alarms,
        "status": report.final_status(),
        "time_in_status_s": report.time_in_status_s(period),
        "excitation": excitation,
    }
    if report.baseline is not None:
        out["baseline"] = {"source": report.baseline.source, **report.baseline.as_dict()}
    return out


def summary_json(data: dict[str, Any]) -> str:
    """Canonical JSON text: fixed key order, shortest round-trip floats, newline at the end."""
    return json.dumps(data, indent=2, allow_nan=False) + "\n"


def _columns(name: str, values: np.ndarray) -> dict[str, np.ndarray]:
    """Split an (N,), (N, 2) or (N, 8) series into scalar columns."""
    if values.ndim == 1:
        return {name: values}
    flat = values.reshape(values.shape[0], int(np.prod(values.shape[1:])))
    width = flat.shape[1]
    if width == 2:
        suffixes: tuple[str, ...] = AXES
    elif width == len(THETA_NAMES):
        suffixes = THETA_NAMES
    else:
        suffixes = tuple(str(i) for i in range(width))
    return {f"{name}_{s}": flat[:, i] for i, s in enumerate(suffixes)}


#: The trace's own columns, before the controller's logged state: name -> (Trace attribute, its column or None).
TRACE_COLUMNS: dict[str, tuple[str, int | None]] = {
    "t_s": ("t_s", None),
    "x_m": ("q_m", 0),
    "y_m": ("q_m", 1),
    "x_meas_m": ("q_meas_m", 0),
    "y_meas_m": ("q_meas_m", 1),
    "x_d_m": ("q_d_m", 0),
    "y_d_m": ("q_d_m", 1),
    "e_x_m": ("e_m", 0),
    "e_y_m": ("e_m", 1),
    "eps_n_m": ("eps_n_m", None),
    "eps_c_m": ("eps_c_m", None),
    "u_x_v": ("u_v", 0),
    "u_y_v": ("u_v", 1),
    "d_x_v": ("disturbance_v", 0),
    "d_y_v": ("disturbance_v", 1),
}


def trace_table(trace: Trace, stride: int = 1, start: int | None = None, stop: int | None = None) -> pa.Table:
    """The trace as one column per scalar series (SI units and volts), every ``stride``-th sample, each column
    of the type it is stored as (:func:`stored_dtype`: float64 time and positions, float32 the others).

    Columns: t_s; x_m, y_m (true position); x_meas_m, y_meas_m (encoder);
    x_d_m, y_d_m (desired); e_x_m, e_y_m; eps_n_m, eps_c_m; u_x_v, u_y_v
    (command); d_x_v, d_y_v (input disturbance); then the controller's logged
    state, e.g. theta_hat_M1 ... theta_hat_dN2, dc_hat_x, dc_hat_y.
    The true parameters at t = 0 are in the schema metadata (``true_theta``,
    JSON); when the scenario changes the plant they are also columns,
    true_theta_M1 ... true_theta_dN2, volt units.
    start, stop: the samples [start, stop) of the run (default: those the
    trace holds, up to ``filled``); a sample is kept when its index in the
    run is a multiple of ``stride``.
    """
    start = trace.first if start is None else start
    stop = trace.filled if stop is None else stop
    kept = -(-start // stride) * stride  # the first multiple of stride from start
    rows = slice(kept - trace.first, max(kept, stop) - trace.first, stride)
    cols: dict[str, np.ndarray] = {}
    for name, (attribute, column) in TRACE_COLUMNS.items():
        values = getattr(trace, attribute)[rows]
        cols[name] = values if column is None else values[:, column]
    for key in sorted(trace.controller_state):
        cols.update(_columns(key, trace.controller_state[key][rows]))
    if trace.true_theta_t is not None:  # the plant changed during the run
        cols.update(_columns("true_theta", trace.true_theta_t[rows]))
    meta = {"true_theta": json.dumps(dict(zip(THETA_NAMES, map(float, trace.true_theta), strict=True)))}
    table = pa.table({k: pa.array(np.ascontiguousarray(v, dtype=stored_dtype(k))) for k, v in cols.items()})
    return table.replace_schema_metadata({**(table.schema.metadata or {}), **meta})


#: The trace columns stored as float64: time and the positions, whose differences are taken (q - q_d, the
#: contour error: nanometres out of 0.25 m need more than float32's 24 bits, which step by 15 nm at 0.25 m and
#: by 0.24 ms at t = 3600 s). Every other column (errors, volts, a controller's logged state, true theta) is
#: float32: 24 bits, a relative step of 6e-8, far below the precision of any figure read from it (docs/cli.md).
FLOAT64_COLUMNS = frozenset(("t_s", "x_m", "y_m", "x_meas_m", "y_meas_m", "x_d_m", "y_d_m"))


def stored_dtype(column: str) -> type[np.floating]:
    """How a trace.parquet column is stored: float64 for FLOAT64_COLUMNS, float32 for any other."""
    return np.float64 if column in FLOAT64_COLUMNS else np.float32


def stored_row_bytes(other_columns: int) -> int:
    """Bytes of one trace.parquet row before compression: the trace's own columns and ``other_columns`` more
    (the controller's logged state, true theta: float32)."""
    own = sum(np.dtype(stored_dtype(name)).itemsize for name in TRACE_COLUMNS)
    return own + other_columns * np.dtype(np.float32).itemsize


#: Parquet writer options: float columns rarely repeat a value, so dictionary pages would only add to the file.
PARQUET_OPTIONS: dict[str, Any] = {"use_dictionary": False}
#: trace.parquet's writer options (sizes and times of the choices: docs/performance.md, "Trace files"):
#: zstd, and BYTE_STREAM_SPLIT, which puts the same byte of every float together (the sign, exponent and
#: high mantissa bytes of a smooth series repeat, and zstd then finds them).
TRACE_PARQUET_OPTIONS: dict[str, Any] = {
    **PARQUET_OPTIONS,
    "compression": "zstd",
    "compression_level": 1,
    "column_encoding": "BYTE_STREAM_SPLIT",
}


def write_parquet(path: Path, table: pa.Table) -> None:
    atomic_write(path, lambda fh: pq.write_table(table, fh, **PARQUET_OPTIONS))


class TraceWriter:
    """trace.parquet written as the run goes (an Observer): every ``stride``-th sample, one row group per piece
    of a run held in pieces (one for a whole run), into a hidden temporary file beside ``path``.

    :meth:`close` completes the file and renames it to ``path``; :meth:`discard`
    removes it. After a fault the file holds every sample before it
    (``on_end`` writes what the last piece holds).
    """

    def __init__(self, path: Path, stride: int = 1) -> None:
        self.path, self.stride = Path(path), int(stride)
        self._fh: IO[bytes] | None = None
        self._tmp: Path | None = None
        self._writer: pq.ParquetWriter | None = None
        self._written = 0  # samples [0, _written) of the run are in the file
        self._empty: pa.Table | None = None
        try:
            with signals_held():
                self._fh, self._tmp = temporary_file(self.path)
        except BaseException:
            self.discard()
            raise

    def on_start(self, run: RunInfo, trace: Trace) -> None:
        pass

    def on_chunk(self, trace: Trace, start: int, stop: int) -> None:
        if stop >= trace.first + trace.t_s.size:  # the end of the piece: its samples go now
            self._write(trace, stop)

    def on_end(self, trace: Trace) -> None:
        self._write(trace, trace.filled)

    def _write(self, trace: Trace, stop: int) -> None:
        table = trace_table(trace, self.stride, self._written, stop)
        if self._writer is None:
            self._writer = pq.ParquetWriter(self._fh, table.schema, **TRACE_PARQUET_OPTIONS)
        if table.num_rows:
            self._writer.write_table(table, row_group_size=table.num_rows)
        self._written = stop

    def close(self) -> None:
        """Complete the file (also with no sample) and rename it to ``path``."""
        assert self._fh is not None and self._tmp is not None, "closed or discarded already"
        if self._writer is None:
            raise RuntimeError("the trace writer saw no run")
        self._writer.close()
        self._writer = None
        commit(self._fh, self._tmp, self.path)
        self._fh = self._tmp = None

    def discard(self) -> None:
        """Remove the temporary file (idempotent)."""
        if self._writer is not None:
            with contextlib.suppress(Exception):
                self._writer.close()
            self._writer = None
        discard(self._fh, self._tmp)
        self._fh = self._tmp = None


class Interrupted(KeyboardInterrupt):
    """SIGINT, SIGTERM or SIGHUP arrived (``signum``): unwinds like Ctrl-C."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


@contextlib.contextmanager
def stop_signals_interrupt() -> Iterator[None]:
    """In the block, the first SIGINT, SIGTERM or SIGHUP raises :class:`Interrupted`; later ones are ignored
    (the clean-up runs undisturbed). The previous handlers come back after the block."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: object) -> None:
        for stop in STOP_SIGNALS:
            signal.signal(stop, signal.SIG_IGN)
        raise Interrupted(signum)

    unraisable = sys.unraisablehook

    def keep_swallowed(info: Any) -> None:
        # A signal that lands in a C callback (numba's compile calls back into Python through ctypes) raises
        # there, and the callback can only print and drop the exception: keep it for raise_swallowed instead.
        if isinstance(info.exc_value, Interrupted):
            _SWALLOWED.append(info.exc_value)
        else:
            unraisable(info)

    previous = {stop: signal.signal(stop, interrupt) for stop in STOP_SIGNALS}
    sys.unraisablehook = keep_swallowed
    try:
        yield
    finally:
        sys.unraisablehook = unraisable
        _SWALLOWED.clear()
        for stop, handler in previous.items():
            signal.signal(stop, handler)


#: Interrupted exceptions a C callback dropped (stop_signals_interrupt), raised again by raise_swallowed.
_SWALLOWED: list[Interrupted] = []


def raise_swallowed() -> None:
    """Raise again an :class:`Interrupted` that a C callback dropped, now that Python is in charge."""
    if _SWALLOWED:
        raise _SWALLOWED.pop()


class SwallowedInterrupt:
    """An Observer that calls :func:`raise_swallowed` at every chunk: a stop signal that arrived while the loop
    compiled stops the run at its first chunk, as one arriving a moment later would."""

    def on_start(self, run: Any, trace: Any) -> None:
        raise_swallowed()

    def on_chunk(self, trace: Any, start: int, stop: int) -> None:
        raise_swallowed()

    def on_end(self, trace: Any) -> None:
        raise_swallowed()
