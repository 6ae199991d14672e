"""``gantry-twin export RUN [--csv] [--out FILE]``: a run's trace.parquet as CSV (docs/cli.md, "export")."""

from __future__ import annotations

import argparse
from pathlib import Path

from gantry_twin.cli.common import writable_file
from gantry_twin.outputs.export import CSV_FILE, ExportError, open_trace, trace_path, write_csv
from gantry_twin.outputs.files import NotRegularFileError
from gantry_twin.outputs.tracefile import TRACE_FILE


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", metavar="RUN", help=f"a run's directory (holding {TRACE_FILE}) or a {TRACE_FILE} file")
    parser.add_argument(
        "--csv", action="store_true", help="write the trace as CSV (the default, and so far the only format)"
    )
    parser.add_argument(
        "--out", metavar="FILE", type=Path, help=f"the CSV file to write (default: RUN/{CSV_FILE}, beside the trace)"
    )


def command(args: argparse.Namespace) -> int:
    """Run ``export``: 0 when the CSV is written; ExportError (exit 2) for a bad RUN or --out.

    An ``--out`` that exists and is not a regular file (a directory, FIFO, socket or device such as /dev/null) is
    refused before anything is read or written, and left as it was.
    """
    source = trace_path(args.run)
    out = args.out if args.out is not None else source.parent / CSV_FILE
    writable_file(out, "--out", "give the CSV file's name")  # before the trace is read
    trace = open_trace(source)
    try:
        write_csv(trace, out, source)
    except NotRegularFileError as exc:  # became one since the check
        raise ExportError(f"--out {out}: {exc.strerror} (give the CSV file's name)") from None
    except OSError as exc:  # reading errors are ExportError (write_csv): this is the writing
        raise ExportError(f"--out {out}: cannot write there ({exc.strerror or exc})") from None
    print(f"{trace.metadata.num_rows} rows x {trace.metadata.num_columns} columns written to {out}")
    return 0
