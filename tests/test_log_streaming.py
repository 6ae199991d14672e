"""Large logs in bounded memory (docs/logs.md, "Bounded time and memory"): ``monitor --log`` reads a log a chunk
at a time and keeps none of its rows; ``identify``, which holds its logs whole, refuses past its cap before
reading the rows. Memory here is counted, not timed: the speed and the peak RSS of a 10-million-row log are
benchmarks/bench_log_memory.py's."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from gantry_twin.sysid.logs import write_log

from .helpers import run_main

#: The memory test's log: 20 s at the machine's 0.2 ms, a slow circle of the carriages.
ROWS = 100_000
#: Rows per chunk in the streamed run, and per row group of the file.
CHUNK_ROWS = 1_000
#: The log's own data, bytes (5 float64 columns, 4 MB): the streamed run's peak must stay below half of it
#: (holding the log's rows as read, even without the estimates, passes it).
LOG_BYTES = ROWS * 5 * 8

#: In a child (a fresh interpreter: its own allocators' high-water marks), ``monitor --log`` twice, a chunk of
#: the whole log first (it also makes the imports and caches a first call makes), then a chunk of CHUNK_ROWS rows;
#: each run's peak of numpy/Python allocations (tracemalloc) and its
#: summary.json, printed as JSON.
CHILD = """
import json, sys, tracemalloc
from gantry_twin.cli import main
from gantry_twin.sysid import logs
log, out, chunks = sys.argv[1], sys.argv[2], [int(c) for c in sys.argv[3:]]
answer = {}
for chunk in chunks:
    logs.LOG_CHUNK_ROWS = chunk
    tracemalloc.start()
    code = main(["monitor", "--log", log, "--out", f"{out}/{chunk}", "--set", "monitor.baseline_window_s=[1,2]",
                 "--set", "monitor.judge_from_s=2"])
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    answer[chunk] = {"code": code, "peak": peak, "summary": open(f"{out}/{chunk}/summary.json").read()}
print(json.dumps(answer))
"""


def _flat(data: object, key: str = "") -> dict[str, object]:
    """A JSON document as {path: leaf}."""
    if isinstance(data, dict):
        return {k: v for name, item in data.items() for k, v in _flat(item, f"{key}/{name}").items()}
    if isinstance(data, list):
        return {k: v for i, item in enumerate(data) for k, v in _flat(item, f"{key}/{i}").items()}
    return {key: data}


def _circle_log(path: Path, rows: int, row_group: int) -> None:
    t = np.arange(rows) * 2e-4
    w = 2.0 * np.pi
    q = 0.05 * np.stack([np.sin(w * t), np.cos(w * t)], axis=1)
    u = 0.5 * np.stack([np.cos(w * t), -np.sin(w * t)], axis=1)
    table = pa.table({"t_s": t, "u_x_v": u[:, 0], "u_y_v": u[:, 1], "x_m": q[:, 0], "y_m": q[:, 1]})
    pq.write_table(table, path, row_group_size=row_group)


def test_monitor_log_holds_a_chunk_not_the_log(tmp_path):
    """Streamed a thousand rows at a time, ``monitor --log``'s peak of numpy and Python allocations stays below
    half the log's own size (0.9 MB for a 4 MB log, measured); the same run with the whole log as one chunk (what
    holding every row costs) peaks far above it, and so does the streamed run when the chunks read are kept
    (checked by hand: 4.8 MB), so the bound can fail. Chunking changes nothing in
    summary.json."""
    log = tmp_path / "log.parquet"
    _circle_log(log, ROWS, 5 * CHUNK_ROWS)
    out = subprocess.run(
        [sys.executable, "-c", CHILD, str(log), str(tmp_path / "out"), str(ROWS), str(CHUNK_ROWS)],
        capture_output=True,
        text=True,
        check=True,
    )
    runs = json.loads(out.stdout.strip().splitlines()[-1])
    streamed, whole = runs[str(CHUNK_ROWS)], runs[str(ROWS)]
    assert streamed["code"] == whole["code"] == 0, out.stderr
    assert streamed["peak"] < LOG_BYTES / 2, f"streamed peak {streamed['peak'] / 1e6:.2f} MB: rows are held"
    assert whole["peak"] > 4 * LOG_BYTES, whole["peak"]  # the measure sees a whole log
    # the same summary, to the rounding of the mean estimates' sums (added a chunk at a time)
    a, b = _flat(json.loads(streamed["summary"])), _flat(json.loads(whole["summary"]))
    assert a.keys() == b.keys()
    for key, value in a.items():
        same = value == pytest.approx(b[key], rel=1e-12) if isinstance(value, float) else value == b[key]
        assert same, (key, value, b[key])
    assert json.loads(streamed["summary"])["steps"] == ROWS


@pytest.mark.parametrize("name", ["log.parquet", "log.csv"])
def test_identify_refuses_a_log_past_its_cap_before_holding_it(tmp_path, capsys, monkeypatch, name):
    """identify holds its logs whole, so it takes at most ROWS_MAX rows in all: past it, one line naming the file,
    the field (rows) and the allowed range, exit 2, nothing written; a parquet log is refused from its footer, a
    CSV log as soon as the rows counted pass the cap. Two logs within the cap each but not together: refused
    naming the second."""
    from gantry_twin.cli import identify

    monkeypatch.setattr(identify, "ROWS_MAX", 1_000)
    t = np.arange(1_500) * 2e-4
    write_log(tmp_path / name, t, np.zeros((t.size, 2)), np.zeros((t.size, 2)), None)
    out = tmp_path / "out"
    code, _, err = run_main(["identify", str(tmp_path / name), "--out", str(out)], capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    counted = "1500" if name.endswith(".parquet") else "more than 1000"
    assert lines[0].startswith(f"gantry-twin: error: {tmp_path / name}: rows: {counted}, allowed 2 to 1000 ("), lines
    assert not out.exists()
    half = tmp_path / f"half-{name}"
    write_log(half, t[:600], np.zeros((600, 2)), np.zeros((600, 2)), None)
    code, _, err = run_main(["identify", str(half), str(half), "--out", str(out)], capsys)
    assert code == 2 and f"{half}: rows: " in err and "allowed 2 to 400 (" in err, err
    assert not out.exists()
