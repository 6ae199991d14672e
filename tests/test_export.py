"""gantry-twin export RUN [--csv] (gantry_twin.outputs.export): the trace as CSV, positions bit for bit."""

from __future__ import annotations

import csv

import numpy as np
import pyarrow.parquet as pq
import pytest

from gantry_twin.outputs import export
from gantry_twin.outputs.tracefile import FLOAT64_COLUMNS

from .helpers import run_main

SHORT = ["--set", "duration_s=0.2", "--set", "window_s=[0.05, 0.2]", "--set", "estimates_window_s=[0.1, 0.2]"]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A 0.2 s DIARC run's directory (its trace: 1000 rows)."""
    from gantry_twin.cli import app as cli

    out = tmp_path_factory.mktemp("export") / "run"
    assert cli.main(["run", "no_load_circle", *SHORT, "--out", str(out), "--no-progress"]) == 0
    return out


def read_csv(path) -> tuple[list[str], list[list[str]]]:
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    return rows[0], rows[1:]


def test_export_writes_every_column_and_the_positions_round_trip_bit_for_bit(run_dir, tmp_path, capsys):
    out = tmp_path / "t.csv"
    code, stdout, err = run_main(["export", str(run_dir), "--csv", "--out", str(out)], capsys)
    assert code == 0, err
    assert f"1000 rows x 34 columns written to {out}" in stdout
    table = pq.read_table(run_dir / "trace.parquet")
    header, rows = read_csv(out)
    assert header == table.column_names and len(rows) == table.num_rows == 1000
    for j, name in enumerate(header):
        stored = table.column(name).to_numpy()
        text = [row[j] for row in rows]
        if name in FLOAT64_COLUMNS:  # time and positions: float64 text -> the same 64 bits
            parsed = np.array([float(v) for v in text])
            np.testing.assert_array_equal(parsed.view(np.int64), stored.view(np.int64), err_msg=name)
        else:  # float32 columns: the shortest text of the float32 value -> the same 32 bits
            parsed32 = np.array(text, dtype=np.float64).astype(np.float32)
            np.testing.assert_array_equal(parsed32.view(np.int32), stored.view(np.int32), err_msg=name)
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary file left


def test_export_writes_beside_the_trace_by_default_and_takes_the_file_itself(run_dir, capsys):
    code, _, err = run_main(["export", str(run_dir), "--csv"], capsys)
    assert code == 0, err
    beside = run_dir / "trace.csv"
    header, rows = read_csv(beside)
    assert len(rows) == 1000
    code, _, err = run_main(["export", str(run_dir / "trace.parquet"), "--csv"], capsys)
    assert code == 0, err
    assert read_csv(beside) == (header, rows)
    beside.unlink()


@pytest.mark.parametrize("what", ["missing", "no_trace", "not_parquet", "out_is_a_directory"])
def test_a_bad_run_is_one_line_and_exit_2_and_writes_nothing(run_dir, tmp_path, capsys, what):
    run, out = str(tmp_path / "nowhere"), tmp_path / "x.csv"
    if what == "no_trace":
        (tmp_path / "empty_run").mkdir()
        run = str(tmp_path / "empty_run")
    elif what == "not_parquet":
        (tmp_path / "trace.parquet").write_text("not parquet\n")
        run = str(tmp_path / "trace.parquet")
    elif what == "out_is_a_directory":
        run, out = str(run_dir), tmp_path
    before = sorted(p.name for p in tmp_path.iterdir())
    code, stdout, err = run_main(["export", run, "--csv", "--out", str(out)], capsys)
    assert code == 2 and stdout == ""
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert err.startswith("gantry-twin: error: ") and (str(out) if what == "out_is_a_directory" else run) in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


KINDS = {"fifo": "a FIFO", "directory": "a directory", "symlink_to_dev_null": "a device"}


@pytest.mark.parametrize("kind", ["fifo", "directory", "symlink_to_dev_null"])
def test_an_out_that_is_not_a_regular_file_is_refused_and_left_as_it_was(run_dir, tmp_path, capsys, kind):
    """Never renamed over: a FIFO stays a FIFO (and is not opened), a directory stays, /dev/null stays a device."""
    import os
    import stat

    out = tmp_path / "x.csv"
    if kind == "fifo":
        os.mkfifo(out)
    elif kind == "directory":
        out.mkdir()
    else:
        out.symlink_to("/dev/null")
    before = os.lstat(out)
    code, stdout, err = run_main(["export", str(run_dir), "--csv", "--out", str(out)], capsys)
    assert code == 2 and stdout == ""
    assert err.strip().splitlines() == [
        f"gantry-twin: error: --out {out}: exists and is {KINDS[kind]}, not a regular file; it is never replaced"
        " (give the CSV file's name)"
    ]
    after = os.lstat(out)
    assert (after.st_ino, stat.S_IFMT(after.st_mode)) == (before.st_ino, stat.S_IFMT(before.st_mode))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.csv"]
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)


def test_the_output_door_never_renames_over_a_fifo(tmp_path):
    """outputs.files.atomic_write: checked again just before the rename (the FIFO appears during the write)."""
    import os
    import stat

    from gantry_twin.outputs.files import NotRegularFileError, atomic_write

    out = tmp_path / "f"
    with pytest.raises(NotRegularFileError):
        atomic_write(out, lambda fh: (fh.write(b"x"), os.mkfifo(out)))
    assert stat.S_ISFIFO(os.lstat(out).st_mode) and [p.name for p in tmp_path.iterdir()] == ["f"]


def test_export_writes_csv_without_the_csv_flag(run_dir, tmp_path, capsys):
    """CSV is the default format: ``export RUN`` and ``export RUN --csv`` write the same file."""
    plain, flagged = tmp_path / "plain.csv", tmp_path / "flagged.csv"
    assert run_main(["export", str(run_dir), "--out", str(plain)], capsys)[0] == 0
    assert run_main(["export", str(run_dir), "--csv", "--out", str(flagged)], capsys)[0] == 0
    assert plain.read_bytes() == flagged.read_bytes()


def test_an_export_that_fails_midway_leaves_no_file(run_dir, tmp_path):
    """Atomic: a failure after the first row group leaves neither the CSV nor a temporary file."""
    trace = export.open_trace(run_dir / "trace.parquet")

    class FailsAtTheSecondGroup:
        schema_arrow, num_row_groups, calls = trace.schema_arrow, 2, []

        def read_row_group(self, group):
            self.calls.append(group)
            if group:
                raise OSError(5, "Input/output error")
            return trace.read_row_group(group)

    failing = FailsAtTheSecondGroup()
    with pytest.raises(export.ExportError, match=r"^RUN in\.parquet: damaged: row group 1 of 2 cannot be read \("):
        export.write_csv(failing, tmp_path / "t.csv", "in.parquet")  # a read that fails is the input's, not --out's
    assert failing.calls == [0, 1] and list(tmp_path.iterdir()) == []
