"""Logs of a real (or simulated) gantry: reading and validating them (docs/logs.md).

A log is a parquet file or a CSV file with a header line and one row per
controller sample:

    t_s             time, s (strictly increasing, one sample period throughout)
    u_x_v, u_y_v    the commanded input of each axis, volts (what the DAC held over the sample)
    x_m, y_m        the encoder positions, metres
    x_d_m, y_d_m    optional: the desired positions, metres

The twin's own ``trace.parquet`` is a log as it is: its encoder columns
``x_meas_m``, ``y_meas_m`` are the positions (its ``x_m``, ``y_m`` are the
true positions, which a real machine never has).

:func:`read_log` checks everything a later step relies on and raises
:class:`LogError`, one line naming the file, the column and the row, for
the first problem. It reads at most the columns it needs, a batch at a time,
checking each batch as it comes, so that a file that is not a log is
refused within its first few kilobytes.
"""

from __future__ import annotations

import functools
import os
import stat
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from gantry_twin.plant.model import AXES, Plant
from gantry_twin.settings import VOLTS_MAX_V, shorten

#: The columns every log has (SI units and volts).
LOG_COLUMNS: tuple[str, ...] = ("t_s", "u_x_v", "u_y_v", "x_m", "y_m")
#: The optional columns: the desired positions, metres.
DESIRED_COLUMNS: tuple[str, ...] = ("x_d_m", "y_d_m")
#: The twin's trace.parquet: its encoder readings are the log's positions.
TRACE_POSITION_COLUMNS = {"x_m": "x_meas_m", "y_m": "y_meas_m"}
#: A position column spanning more than the travel (:func:`travel_span_m`) times 1 + TRAVEL_SLACK, or
#: farther than that from 0, is not in metres (millimetres, most likely).
TRAVEL_SLACK = 0.1
#: Fastest believable carriage speed between two samples, m/s (a position log in mm moves 1000x faster).
SPEED_MAX_M_S = 10.0
#: Sample-to-sample jitter of t_s accepted, as a fraction of the sample period.
PERIOD_TOLERANCE = 0.01
#: Most samples read from one log: an hour at 5 kHz (the longest scenario, at the controller's rate).
LOG_MAX_ROWS = 18_000_000
#: The header of a CSV log must end within this many bytes.
HEADER_MAX_BYTES = 64 * 1024
#: Bytes per CSV block read (pyarrow's block size): a CSV log's chunk.
CSV_BLOCK_BYTES = 1 << 20
#: Rows per parquet batch read (a parquet log's chunk, whatever its row groups).
LOG_CHUNK_ROWS = 1 << 16
PARQUET_MAGIC = b"PAR1"


@functools.cache
def travel_span_m() -> float:
    """The longest axis travel of the shipped model (its joint ranges), m: 510 mm on the Anorad HERC-510-510."""
    plant = Plant()
    ranges = plant.model.jnt_range[[plant.model.joint(a).id for a in AXES]]
    return float(np.max(ranges[:, 1] - ranges[:, 0]))


class LogError(ValueError):
    """A log that cannot be used: one line naming the file, the column and row, and what is wrong."""


#: A log's sample period may differ from the machine's by this fraction (the clock of a logger, rounding of t_s).
PERIOD_MATCH = 0.01
#: What a period this many times the machine's suggests t_s was written in.
_UNIT_GUESSES = ((1e3, "t_s looks like milliseconds"), (1e6, "t_s looks like microseconds"))


def check_sample_period(label: str, period_s: float, machine_s: float, exact: bool = True) -> None:
    """LogError (exit 2) unless the log's sample period is the machine's (``exact``: DIARC's estimator and the
    monitor run at that rate), or else (``exact=False``, identification, which takes the log's own period) unless
    it is 1000 or 10^6 times the machine's: t_s written in milliseconds or microseconds. ``label`` names the log."""
    if abs(period_s - machine_s) <= PERIOD_MATCH * machine_s:
        return
    ratio = period_s / machine_s
    guess = next((why for factor, why in _UNIT_GUESSES if abs(ratio / factor - 1.0) <= PERIOD_MATCH), "")
    if not exact and not guess:
        return
    raise LogError(
        f"{label}: its sample period is {period_s:.6g} s (t_s in seconds), not the machine's "
        f"{machine_s * 1e3:g} ms" + (f": {guess}; give t_s in seconds" if guess else "; give a log sampled at it")
    )


@dataclass(frozen=True)
class Log:
    """A validated log. t_s (N,) s; u_v (N, 2) volts; q_m (N, 2) encoder positions m; q_d_m (N, 2) or None."""

    path: str
    t_s: np.ndarray
    u_v: np.ndarray
    q_m: np.ndarray
    q_d_m: np.ndarray | None
    sample_period_s: float

    @property
    def samples(self) -> int:
        return int(self.t_s.size)

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0] + self.sample_period_s)


@dataclass(frozen=True)
class LogInfo:
    """What a validated log holds, without its rows (:func:`scan_log`): samples, sample period, first and last t_s."""

    path: str
    samples: int
    sample_period_s: float
    t_first_s: float
    t_last_s: float
    has_desired: bool

    @property
    def duration_s(self) -> float:
        return float(self.t_last_s - self.t_first_s + self.sample_period_s)


@dataclass(frozen=True)
class LogChunk:
    """Rows [first, first + len(t_s)) of a validated log: t_s (n,), u_v, q_m (n, 2), q_d_m (n, 2) or None."""

    first: int
    t_s: np.ndarray
    u_v: np.ndarray
    q_m: np.ndarray
    q_d_m: np.ndarray | None


def scan_log(path: str | Path) -> LogInfo:
    """Read and validate a log a chunk at a time, keeping none of its rows; :class:`LogError` on the first problem."""
    checker = _open_checked(str(path))
    for _ in checker.chunks():
        pass
    return checker.info()


def log_chunks(path: str | Path) -> Iterator[LogChunk]:
    """The log's rows a chunk at a time (LOG_CHUNK_ROWS rows of parquet, CSV_BLOCK_BYTES of CSV), each validated
    as it comes (:class:`LogError`); for the consumers that work chunk by chunk (``monitor --log``)."""
    return _open_checked(str(path)).chunks()


def read_log(path: str | Path, max_rows: int = LOG_MAX_ROWS, reader: str = "") -> Log:
    """Read and validate a whole log (module docstring); :class:`LogError` on the first problem, and when it has
    more than ``max_rows`` rows: refused before they are read when the file says how many it has (parquet), else
    as soon as they are counted (CSV), so memory stays within ``max_rows``. ``reader`` says who holds the rows
    whole and why, for the message (e.g. "identify holds its logs whole: ...")."""
    name = str(path)
    checker = _open_checked(name)
    rows = checker.declared_rows
    if rows is not None and rows > max_rows:
        raise _too_many(name, str(rows), max_rows, reader)
    parts: list[LogChunk] = []
    for chunk in checker.chunks():
        if chunk.first + chunk.t_s.size > max_rows:
            raise _too_many(name, f"more than {max_rows}", max_rows, reader)
        parts.append(chunk)
    info = checker.info()
    desired = np.concatenate([c.q_d_m for c in parts]) if info.has_desired else None
    return Log(
        name,
        np.concatenate([c.t_s for c in parts]),
        np.concatenate([c.u_v for c in parts]),
        np.concatenate([c.q_m for c in parts]),
        desired,
        info.sample_period_s,
    )


def _too_many(path: str, rows: str, max_rows: int, reader: str) -> LogError:
    return _fail(path, f"rows: {rows}, allowed 2 to {max_rows}" + (f" ({reader})" if reader else ""))


def _open_checked(name: str) -> _Checker:
    _check_file(name)
    with open(name, "rb") as fh:
        head = fh.read(HEADER_MAX_BYTES)
    if head.startswith(PARQUET_MAGIC):
        batches, columns, rows = _parquet_batches(name)
    else:
        (batches, columns), rows = _csv_batches(name, head), None
    return _Checker(name, batches, columns, rows)


def _fail(path: str, message: str) -> LogError:
    return LogError(f"{path}: {message}")


def _check_file(path: str) -> None:
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise _fail(path, "no such file; give a log (parquet or CSV, docs/logs.md)") from None
    except OSError as exc:
        raise _fail(path, f"cannot read ({exc.strerror})") from None
    if not stat.S_ISREG(info.st_mode):
        raise _fail(path, "is not a regular file; give a log (parquet or CSV, docs/logs.md)")
    if info.st_size == 0:
        raise _fail(path, "is empty: no header, no rows")


def _mapping(path: str, names: list[str]) -> dict[str, str]:
    """Log column -> the file's column, or LogError naming the first missing one."""
    present = set(names)
    trace = all(c in present for c in TRACE_POSITION_COLUMNS.values())
    mapping = {c: (TRACE_POSITION_COLUMNS.get(c, c) if trace else c) for c in LOG_COLUMNS}
    for column, source in mapping.items():
        if source not in present:
            shown = ", ".join(names[:8]) + (", ..." if len(names) > 8 else "")
            raise _fail(
                path, f"missing column {column} (a log needs {', '.join(LOG_COLUMNS)}; the file has: {shown or 'none'})"
            )
    for column in DESIRED_COLUMNS:
        if column in present:
            mapping[column] = column
    return mapping


def _parquet_batches(path: str):
    try:
        pf = pq.ParquetFile(path)
    except (pa.ArrowException, OSError) as exc:
        raise _fail(path, f"starts like parquet but is not a readable parquet file ({_first_line(exc)})") from None
    mapping = _mapping(path, pf.schema_arrow.names)
    rows = pf.metadata.num_rows
    if rows > LOG_MAX_ROWS:
        raise _fail(path, f"has {rows} rows, more than the {LOG_MAX_ROWS} a log may have")
    t_f32 = pf.schema_arrow.field(mapping["t_s"]).type == pa.float32()

    def batches():
        # LOG_CHUNK_ROWS at a time (a writer's row group may be a million rows or the whole file), one row group
        # after another: one iter_batches over all of them let Arrow's pool grow with them (86 MB for 10 groups
        # of 100 000 rows, against 25 MB).
        try:
            for group in range(pf.num_row_groups):
                for batch in pf.iter_batches(
                    batch_size=LOG_CHUNK_ROWS, row_groups=[group], columns=list(mapping.values()), use_threads=False
                ):
                    yield {c: _floats(path, batch.column(s), c) for c, s in mapping.items()} | {"t_f32": t_f32}
        except (pa.ArrowException, OSError) as exc:
            raise _fail(path, f"cannot read its data ({_first_line(exc)})") from None

    return batches(), list(mapping), rows


def _csv_batches(path: str, head: bytes):
    import pyarrow.csv as pacsv  # here, not at the top: the command line's start-up does not pay for it

    if b"\0" in head:
        raise _fail(path, "is neither parquet nor a CSV text file (binary content in its first bytes)")
    lines = head.splitlines(keepends=True)
    skip = 0
    for line in lines:  # leading comment lines (# ...) and blank lines
        if line.strip() and not line.lstrip().startswith(b"#"):
            break
        skip += 1
    if skip == len(lines) or (skip == len(lines) - 1 and len(head) == HEADER_MAX_BYTES):
        raise _fail(path, f"no CSV header line within its first {HEADER_MAX_BYTES // 1024} KiB")
    try:
        header = lines[skip].decode("utf-8")
    except UnicodeDecodeError:
        raise _fail(path, "is neither parquet nor a UTF-8 CSV file (its header is not text)") from None
    names = [n.strip().strip('"').strip() for n in header.strip().split(",")]
    mapping = _mapping(path, names)
    index = {n: i for i, n in enumerate(names)}
    generated = [f"c{i}" for i in range(len(names))]
    wanted = {c: generated[index[s]] for c, s in mapping.items()}
    read = pacsv.ReadOptions(skip_rows=skip + 1, column_names=generated, block_size=CSV_BLOCK_BYTES)
    convert = pacsv.ConvertOptions(
        include_columns=list(wanted.values()), column_types={g: pa.string() for g in wanted.values()}
    )
    parse = pacsv.ParseOptions(ignore_empty_lines=True)

    def batches():
        try:
            reader = pacsv.open_csv(path, read_options=read, parse_options=parse, convert_options=convert)
            for batch in reader:
                yield {c: _floats(path, batch.column(batch.schema.get_field_index(g)), c) for c, g in wanted.items()}
        except pa.ArrowException as exc:
            raise _fail(path, f"is not a CSV log ({_first_line(exc)})") from None

    return batches(), list(mapping)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return (text[0] if text else type(exc).__name__)[:160]


class _BadValue(Exception):
    """A CSV cell that is not a number: its column and index in the batch."""

    def __init__(self, column: str, index: int, text: object) -> None:
        super().__init__(column)
        self.column, self.index, self.text = column, index, text


def _floats(path: str, column, name: str) -> np.ndarray:
    """A column as float64; CSV text is parsed here (spaces around numbers allowed), _BadValue on a non-number."""
    if pa.types.is_string(column.type) or pa.types.is_large_string(column.type):
        import pyarrow.compute as pc

        try:
            column = pc.cast(pc.utf8_trim_whitespace(column), pa.float64())
        except pa.ArrowInvalid:
            for i, text in enumerate(column.to_pylist()):  # this batch only: find the row to name
                try:
                    float(text)
                except (TypeError, ValueError):
                    raise _BadValue(name, i, text) from None
            raise
    if not (pa.types.is_floating(column.type) or pa.types.is_integer(column.type)):
        raise _fail(path, f"column {name}: {column.type} values, not numbers")
    return np.asarray(column.to_numpy(zero_copy_only=False), dtype=np.float64)


def _named_rows(path: str, batches):
    """The batches, a _BadValue turned into a LogError naming its row."""
    before = 0
    try:
        for batch in batches:
            yield batch
            before += batch["t_s"].size
    except _BadValue as bad:
        text = bad.text if bad.text is None else shorten(str(bad.text), 40)
        raise _fail(path, f"column {bad.column}, row {before + bad.index + 1}: {text!r} is not a number") from None


class _Checker:
    """Checks a log's batches as they come (each check carries over the batch boundaries); :meth:`chunks` yields
    them as :class:`LogChunk` and keeps none; :meth:`info` after the last."""

    def __init__(self, path: str, batches, columns: list[str], declared_rows: int | None) -> None:
        self.path, self._batches, self._columns, self.declared_rows = path, batches, columns, declared_rows
        self.rows = 0
        self.period: float | None = None
        self.first_t: float | None = None
        self.last_t: float | None = None
        self._extent = {c: [np.inf, -np.inf] for c in ("x_m", "y_m", *DESIRED_COLUMNS)}
        self._last_q: dict[str, float] = {}

    def chunks(self) -> Iterator[LogChunk]:
        path, columns = self.path, self._columns
        desired = all(c in columns for c in DESIRED_COLUMNS)
        for batch in _named_rows(path, self._batches):
            n = batch["t_s"].size
            if n == 0:
                continue
            self._check(batch)
            yield LogChunk(
                self.rows,
                batch["t_s"],
                np.stack([batch["u_x_v"], batch["u_y_v"]], axis=1),
                np.stack([batch["x_m"], batch["y_m"]], axis=1),
                np.stack([batch["x_d_m"], batch["y_d_m"]], axis=1) if desired else None,
            )
            if self.first_t is None:
                self.first_t = float(batch["t_s"][0])
            self.rows += n
            self.last_t = float(batch["t_s"][-1])
        if self.rows == 0:
            raise _fail(path, "has a header but no rows")
        if self.rows == 1:
            raise _fail(path, "has one row; a log needs at least two (the sample period comes from t_s)")

    def info(self) -> LogInfo:
        """The log's sample period is its mean step (the same however it was chunked; each step was checked
        within PERIOD_TOLERANCE of the first chunk's median)."""
        assert self.period is not None and self.first_t is not None and self.last_t is not None
        has_desired = all(c in self._columns for c in DESIRED_COLUMNS)
        period = (self.last_t - self.first_t) / (self.rows - 1)
        return LogInfo(self.path, self.rows, period, self.first_t, self.last_t, has_desired)

    def _check(self, batch: dict) -> None:
        path, rows, n = self.path, self.rows, batch["t_s"].size
        if rows + n > LOG_MAX_ROWS:
            raise _fail(path, f"has more than {LOG_MAX_ROWS} rows, the most a log may have")
        for c in self._columns:
            bad = ~np.isfinite(batch[c])
            if bad.any():
                i = int(np.argmax(bad))
                raise _fail(path, f"column {c}, row {rows + i + 1}: {batch[c][i]} is not a finite number")
        last_t = self.last_t
        t = batch["t_s"] if last_t is None else np.concatenate([[last_t], batch["t_s"]])
        dt = np.diff(t)
        offset = rows - (0 if last_t is None else 1)  # row (0-based) of t[0]
        if dt.size:
            worse = dt <= 0.0
            if worse.any():
                i = int(np.argmax(worse))
                raise _fail(
                    path,
                    f"column t_s, row {offset + i + 2}: time {t[i + 1]:.9g} s is not after the row before "
                    f"({t[i]:.9g} s); time must increase",
                )
            if self.period is None:
                self.period = float(np.median(dt))
            period = self.period
            # A float32 time column (a compressed trace) rounds each time to its float32 spacing.
            rounding = 2.0 * np.spacing(np.abs(t[1:]).astype(np.float32)).astype(float) if batch.get("t_f32") else 0.0
            mixed = np.abs(dt - period) > PERIOD_TOLERANCE * period + rounding
            if mixed.any():
                i = int(np.argmax(mixed))
                raise _fail(
                    path,
                    f"column t_s, row {offset + i + 2}: step {dt[i]:.6g} s differs from the sample period "
                    f"{period:.6g} s (mixed sample periods or missing rows; a log has one period)",
                )
        for c in ("u_x_v", "u_y_v"):
            over = np.abs(batch[c]) > VOLTS_MAX_V * (1.0 + 1e-9)
            if over.any():
                i = int(np.argmax(over))
                raise _fail(
                    path,
                    f"column {c}, row {rows + i + 1}: {batch[c][i]:.6g} V is outside the DAC range "
                    f"+-{VOLTS_MAX_V:g} V (inputs are volts)",
                )
        extent, last_q, period = self._extent, self._last_q, self.period
        for c in extent:
            if c not in batch:
                continue
            q = batch[c]
            lo, hi = extent[c]
            extent[c] = [min(lo, float(q.min())), max(hi, float(q.max()))]
            limit = travel_span_m() * (1.0 + TRAVEL_SLACK)
            far = np.abs(q) > limit
            if far.any() or extent[c][1] - extent[c][0] > limit:
                i = int(np.argmax(far)) if far.any() else int(np.argmax(q) if q.max() == extent[c][1] else np.argmin(q))
                raise _fail(
                    path,
                    f"column {c}, row {rows + i + 1}: {q[i]:.6g} is beyond the {travel_span_m():g} m travel "
                    f"(the column spans {extent[c][0]:.6g} to {extent[c][1]:.6g}): positions must be metres "
                    "(millimetres given?)",
                )
            prev = last_q.get(c)
            if period is not None and (q.size > 1 or prev is not None):
                seq = q if prev is None else np.concatenate([[prev], q])
                step = np.abs(np.diff(seq))
                jump = step > SPEED_MAX_M_S * period
                if jump.any():
                    j = int(np.argmax(jump))
                    raise _fail(
                        path,
                        f"column {c}, row {rows + j + 1 + (prev is None)}: moves {step[j]:.6g} in one sample, "
                        f"faster than {SPEED_MAX_M_S:g} m/s: positions must be metres (millimetres given?)",
                    )
            last_q[c] = float(q[-1])


def centred_velocity(q_m: np.ndarray, half_width: int, sample_period_s: float) -> np.ndarray:
    """Velocity over the sample before each one (k-1 -> k), m/s: the difference of positions half_width
    samples before and after that interval (fewer at the ends); entry 0 is that of the first interval."""
    n = q_m.shape[0]
    k = np.arange(1, n)
    hi = np.minimum(k - 1 + half_width, n - 1)
    lo = np.maximum(k - half_width, 0)
    span_s = ((hi - lo) * sample_period_s).reshape((-1,) + (1,) * (q_m.ndim - 1))
    v = (q_m[hi] - q_m[lo]) / span_s
    return np.concatenate([v[:1], v])


def write_log(path: str | Path, t_s: np.ndarray, u_v: np.ndarray, q_m: np.ndarray, q_d_m: np.ndarray | None) -> None:
    """Write a log (parquet, or CSV when the name ends in .csv), columns in LOG_COLUMNS' order."""
    cols = {"t_s": t_s, "u_x_v": u_v[:, 0], "u_y_v": u_v[:, 1], "x_m": q_m[:, 0], "y_m": q_m[:, 1]}
    if q_d_m is not None:
        cols.update({"x_d_m": q_d_m[:, 0], "y_d_m": q_d_m[:, 1]})
    write_columns(path, cols)


def write_columns(path: str | Path, columns: dict[str, np.ndarray]) -> None:
    """Float64 columns to parquet, or to CSV when the name ends in .csv."""
    import pyarrow.csv as pacsv

    table = pa.table({k: pa.array(np.ascontiguousarray(v, dtype=np.float64)) for k, v in columns.items()})
    if str(path).endswith(".csv"):
        pacsv.write_csv(table, str(path))
    else:
        pq.write_table(table, str(path))
