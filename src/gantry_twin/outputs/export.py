"""``gantry-twin export RUN --csv [--out FILE]``: a run's trace.parquet as CSV, for tools without Parquet.

One header row of the trace's column names (docs/cli.md, "trace.parquet columns"), then one row per
sample. Each value is the shortest decimal text that reads back to the same number (Arrow's CSV
writer): the float64 columns (time and positions) round-trip bit for bit when parsed as float64
(Python's ``float``, NumPy's float64); the float32 columns when parsed as float32. The trace's schema
metadata (``true_theta``) is not in the CSV: it is in summary.json. The file is written a row group
at a time (memory does not grow with the run) into a temporary file renamed at the end
(:func:`gantry_twin.outputs.files.atomic_write`): an interrupted export leaves no partial CSV.
"""

from __future__ import annotations

from pathlib import Path
from typing import IO

import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from gantry_twin.inputs import InputFileError, check_input_file
from gantry_twin.outputs.files import atomic_write
from gantry_twin.outputs.rundirs import resolve_run
from gantry_twin.outputs.tracefile import TRACE_FILE

#: The CSV's name beside the trace when --out is not given.
CSV_FILE = "trace.csv"


class ExportError(Exception):
    """RUN is not a run with a trace, or the CSV cannot be written there (exit code 2, one line)."""


def trace_path(run: str | Path) -> Path:
    """The trace.parquet of ``run`` (a run directory, ``runs/<name>`` or its ``latest`` as ``compare`` takes them,
    or the file itself); ExportError if there is none."""
    try:
        path = resolve_run(Path(run))
    except InputFileError as exc:  # a ``latest`` text file that is not one
        raise ExportError(f"RUN {exc}") from None
    if path.is_dir():
        if not (path / TRACE_FILE).is_file():
            raise ExportError(f"RUN {path}: no {TRACE_FILE} in it (a run written with outputs.trace: false?)")
        return path / TRACE_FILE
    if not path.exists():
        raise ExportError(f"RUN {path}: no such run directory or file")
    try:  # a FIFO would block the open, a device read without end: refused before either
        check_input_file(path, f"a run's directory or its {TRACE_FILE}")
    except InputFileError as exc:
        raise ExportError(f"RUN {path}: {exc}") from None
    return path


def open_trace(path: Path) -> pq.ParquetFile:
    """The Parquet file at ``path``; ExportError if it is not one."""
    try:
        return pq.ParquetFile(path)
    except (pa.ArrowException, OSError) as exc:
        raise ExportError(f"RUN {path}: not a readable Parquet trace ({str(exc).splitlines()[0]})") from None


def write_csv(trace: pq.ParquetFile, out: Path, source: Path | str = "") -> None:
    """Write the trace as CSV to ``out`` atomically, one row group at a time.

    A row group that cannot be read (a damaged page: a decompression error, a bad checksum; Arrow raises some of
    these as OSError) is ExportError naming ``source`` and the row group, never an error of ``out``; the partial
    CSV is removed."""

    def write(fh: IO[bytes]) -> None:
        with pacsv.CSVWriter(fh, trace.schema_arrow) as writer:
            for group in range(trace.num_row_groups):
                try:
                    table = trace.read_row_group(group)
                except (pa.ArrowException, OSError) as exc:
                    raise ExportError(
                        f"RUN {source}: damaged: row group {group} of {trace.num_row_groups} cannot be read "
                        f"({str(exc).splitlines()[0]}); nothing written"
                    ) from None
                writer.write_table(table)

    atomic_write(out, write)
