"""The log format (docs/logs.md): a hand-written CSV, the twin's own trace, and bad logs refused fast."""

from __future__ import annotations

import os
import time

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from gantry_twin.cli import main
from gantry_twin.sysid.logs import LogError, read_log, write_log

# Typed by hand, as a user would: a comment line, spaces after commas, an extra column, a CRLF line end,
# a blank line at the end, numbers written several ways.
HAND_CSV = (
    "# gantry log, 5 kHz, written by hand\n"
    "t_s, u_x_v, u_y_v, x_m, y_m, note\n"
    "0.0000, 0.10, -0.2, 0, 0.0, 1\n"
    "0.0002, 1e-1, -0.20, 0.0000005, -1.0e-6, 2\r\n"
    "0.0004,0.25,-.1,1E-6,-0.0000015,3\n"
    "\n"
)


def test_hand_written_csv_is_read_exactly(tmp_path):
    path = tmp_path / "hand.csv"
    path.write_bytes(HAND_CSV.encode())
    log = read_log(path)
    np.testing.assert_array_equal(log.t_s, [0.0, 0.0002, 0.0004])
    np.testing.assert_array_equal(log.u_v, [[0.1, -0.2], [0.1, -0.2], [0.25, -0.1]])
    np.testing.assert_array_equal(log.q_m, [[0.0, 0.0], [0.5e-6, -1.0e-6], [1.0e-6, -1.5e-6]])
    assert log.q_d_m is None
    assert log.sample_period_s == pytest.approx(0.0002, rel=1e-12)


def _twin_trace_table(n: int = 50) -> pa.Table:
    """A table with the columns of the twin's trace.parquet (tracefile.trace_table), true and encoder positions."""
    rng = np.random.default_rng(0)
    t = np.arange(n) * 2e-4
    q = np.cumsum(rng.normal(0.0, 1e-5, (n, 2)), axis=0)
    meas = np.round(q / 0.5e-6) * 0.5e-6
    cols = {
        "t_s": t,
        "x_m": q[:, 0],
        "y_m": q[:, 1],
        "x_meas_m": meas[:, 0],
        "y_meas_m": meas[:, 1],
        "x_d_m": q[:, 0] + 1e-6,
        "y_d_m": q[:, 1] - 1e-6,
        "u_x_v": rng.normal(0, 1, n),
        "u_y_v": rng.normal(0, 1, n),
        "theta_hat_M1": np.full(n, 0.12),
    }
    return pa.table(cols)


def test_twin_trace_is_a_log_with_its_encoder_positions(tmp_path):
    table = _twin_trace_table()
    path = tmp_path / "trace.parquet"
    pq.write_table(table, path)
    log = read_log(path)
    np.testing.assert_array_equal(log.q_m[:, 0], table.column("x_meas_m").to_numpy())  # not the true x_m
    np.testing.assert_array_equal(log.q_m[:, 1], table.column("y_meas_m").to_numpy())
    np.testing.assert_array_equal(log.q_d_m[:, 0], table.column("x_d_m").to_numpy())
    np.testing.assert_array_equal(log.u_v[:, 1], table.column("u_y_v").to_numpy())


def test_float32_columns_are_read_as_float64(tmp_path):
    """A compressed trace stores some columns as float32 (docs/cli.md): still a log, times to float32 rounding."""
    table = _twin_trace_table(3000)
    table = table.set_column(0, "t_s", pa.array(table.column("t_s").to_numpy() + 60.0, pa.float32()))
    table = table.set_column(3, "x_meas_m", pa.array(table.column("x_meas_m").to_numpy(), pa.float32()))
    path = tmp_path / "trace.parquet"
    pq.write_table(table, path)
    log = read_log(path)
    assert log.t_s.dtype == np.float64 and log.q_m.dtype == np.float64
    assert log.sample_period_s == pytest.approx(2e-4, rel=0.05)


def test_write_log_round_trip(tmp_path):
    t = np.arange(10) * 1e-3
    u = np.stack([np.sin(t), np.cos(t)], axis=1)
    q = np.stack([t * 0.1, -t * 0.1], axis=1)
    for name in ("log.parquet", "log.csv"):
        write_log(tmp_path / name, t, u, q, q + 1e-6)
        log = read_log(tmp_path / name)
        np.testing.assert_array_equal(log.u_v, u)
        np.testing.assert_array_equal(log.q_d_m, q + 1e-6)


GOOD_ROWS = [f"{k * 0.0002:.4f},0.1,-0.1,{k * 1e-5:.6f},{-k * 1e-5:.6f}" for k in range(6)]
HEADER = "t_s,u_x_v,u_y_v,x_m,y_m"


def _csv(rows, header=HEADER):
    return "\n".join([header, *rows]) + "\n"


def _replace(row: int, column: int, value: str) -> list[str]:
    rows = [r.split(",") for r in GOOD_ROWS]
    rows[row][column] = value
    return [",".join(r) for r in rows]


BAD_LOGS = {
    "missing column": (_csv([r.rsplit(",", 1)[0] for r in GOOD_ROWS], "t_s,u_x_v,u_y_v,x_m"), "missing column y_m"),
    "time not increasing": (_csv(_replace(3, 0, "0.0004")), "column t_s, row 4: time 0.0004 s is not after"),
    "NaN": (_csv(_replace(2, 3, "nan")), "column x_m, row 3: nan is not a finite number"),
    "not a number": (_csv(_replace(4, 2, "abc")), "column u_y_v, row 5"),
    "positions in mm": (
        _csv([f"{k * 0.0002:.4f},0.1,-0.1,{120 + k * 0.01:.3f},0" for k in range(6)]),
        "column x_m, row 1: 120 is beyond the 0.51 m travel",
    ),
    "mixed sample periods": (
        _csv(GOOD_ROWS + [f"{0.001 + k * 0.001:.4f},0.1,-0.1,0.00005,-0.00005" for k in range(1, 4)]),
        "column t_s, row 7: step 0.001 s differs from the sample period",
    ),
    "volts beyond the DAC": (_csv(_replace(1, 1, "25")), "column u_x_v, row 2"),
    "empty": ("", "is empty"),
    "header only": (_csv([]), "no rows"),
    "one row": (_csv(GOOD_ROWS[:1]), "one row"),
}


@pytest.mark.parametrize("case", sorted(BAD_LOGS))
def test_bad_log_exit_2_one_line_naming_column_and_row(tmp_path, capsys, case):
    text, expected = BAD_LOGS[case]
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(LogError, match=expected):
        read_log(path)
    assert main(["identify", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and expected in err, err
    assert not (tmp_path / "out").exists()


def test_positions_in_mm_of_a_small_motion_are_caught_by_their_speed(tmp_path):
    """0.08 mm per sample (0.4 m/s in mm) read as metres is 400 m/s."""
    rows = [f"{k * 0.0002:.4f},0.1,-0.1,{0.08 * k:.3f},0" for k in range(3)]
    path = tmp_path / "mm.csv"
    path.write_text(_csv(rows))
    with pytest.raises(LogError, match=r"column x_m, row 2: moves .* m/s: positions must be metres"):
        read_log(path)


@pytest.mark.parametrize("start", [b"\x00\x01junk", b"PAR1 but not parquet", b"lorem ipsum dolor " * 4000])
def test_two_gigabytes_of_junk_refused_within_5_s(tmp_path, capsys, start):
    path = tmp_path / "junk.parquet"
    with open(path, "wb") as fh:
        fh.write(start)
        fh.truncate(2 * 1024**3)  # sparse: 2 GB on the file system, none of it read
    assert os.path.getsize(path) == 2 * 1024**3
    began = time.process_time()  # CPU time: the work done, which a loaded machine does not change
    assert main(["monitor", "--log", str(path), "--out", str(tmp_path / "out")]) == 2
    assert time.process_time() - began < 5.0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err, err
