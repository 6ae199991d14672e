"""trace.parquet: one column per scalar series of a run, written as the run goes (docs/cli.md, "Trace files")."""

from __future__ import annotations

import contextlib
import json
from pathlib import Path
from typing import IO, Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from gantry_twin.loop.trace import RunInfo, Trace
from gantry_twin.outputs.files import PARQUET_OPTIONS, commit, discard, temporary_file, write_parquet
from gantry_twin.outputs.signals import signals_held
from gantry_twin.plant.model import AXES, THETA_NAMES

#: A run's trace file in its directory (docs/cli.md).
TRACE_FILE = "trace.parquet"


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


#: trace.parquet's writer options (sizes and times of the choices: docs/performance.md, "Trace files"):
#: zstd, and BYTE_STREAM_SPLIT, which puts the same byte of every float together (the sign, exponent and
#: high mantissa bytes of a smooth series repeat, and zstd then finds them).
TRACE_PARQUET_OPTIONS: dict[str, Any] = {
    **PARQUET_OPTIONS,
    "compression": "zstd",
    "compression_level": 1,
    "column_encoding": "BYTE_STREAM_SPLIT",
}


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


#: Samples per trace part of a live run (1 s at 5 kHz), and the parts' names in its trace/ directory.
PART_SAMPLES = 5000
PART_PATTERN = "part-{:06d}.parquet"


class TraceParts:
    """A live run's trace as it comes (an Observer): a part file every ``part_samples`` samples into ``directory``
    (``part-000001.parquet``, ..., each a complete parquet file of trace.parquet's columns, written atomically),
    so that a run killed at any moment leaves a readable trace of what it ran, as the shadow monitor writes its
    own (docs/live-link.md). ``on_end`` writes the last, shorter part."""

    def __init__(self, directory: Path, part_samples: int = PART_SAMPLES) -> None:
        self.directory, self.part_samples = Path(directory), int(part_samples)
        self._tables: list[pa.Table] = []
        self._held = 0
        self.parts = 0

    def on_start(self, run: RunInfo, trace: Trace) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)

    def on_chunk(self, trace: Trace, start: int, stop: int) -> None:
        self._tables.append(trace_table(trace, 1, start, stop))
        self._held += stop - start
        if self._held >= self.part_samples:
            self.flush()

    def on_end(self, trace: Trace) -> None:
        self.flush()

    def flush(self) -> None:
        """Write what is held as the next part (nothing when nothing is held)."""
        if not self._tables:
            return
        table = pa.concat_tables(self._tables)
        self._tables, self._held = [], 0
        self.parts += 1
        write_parquet(self.directory / PART_PATTERN.format(self.parts), table)
