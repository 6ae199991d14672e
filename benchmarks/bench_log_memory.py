"""Peak memory of ``monitor --log`` and ``identify`` on a 1-million-row and a 10-million-row log, side by side.

    PYTHONPATH=src python benchmarks/bench_log_memory.py [--rows 1000000 10000000] [--dir DIR]

The logs are the twin's own: one ``gantry-twin excite`` log (20 s, 100 000 rows, starting and ending at
rest at the centre) repeated end to end with t_s running on, written a copy at a time (row groups of 100 000
rows), so each is a valid log of the machine. Each command runs in a child process; its peak resident set
is the child's ``ru_maxrss`` (os.wait4), with its exit code and wall time. The commands compile nothing
here once the cache is warm: a first run (on the smallest log) warms it and is not counted.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq


def make_log(seed_log: Path, rows: int, path: Path) -> None:
    """``rows`` rows of ``seed_log`` repeated with t_s running on, a copy at a time."""
    seed = pq.read_table(seed_log, columns=["t_s", "u_x_v", "u_y_v", "x_m", "y_m", "x_d_m", "y_d_m"])
    n = seed.num_rows
    t = seed.column("t_s").to_numpy()
    period = float(t[1] - t[0])
    with pq.ParquetWriter(path, seed.schema) as writer:
        done = 0
        while done < rows:
            part = seed.slice(0, min(n, rows - done))
            shifted = part.set_column(0, "t_s", pa.array(t[: part.num_rows] + done * period))
            writer.write_table(shifted, row_group_size=n)
            done += part.num_rows


def peak(command: list[str]) -> tuple[int, float, float, str]:
    """Run a command in a child; (exit code, peak RSS MB, wall s, last stderr line)."""
    start = time.perf_counter()
    with tempfile.TemporaryFile() as err:
        child = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=err)
        _, status, usage = os.wait4(child.pid, 0)
        child.returncode = os.waitstatus_to_exitcode(status)
        err.seek(0)
        lines = err.read().decode(errors="replace").strip().splitlines()
    return child.returncode, usage.ru_maxrss / 1024.0, time.perf_counter() - start, (lines[-1] if lines else "")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, nargs="+", default=[1_000_000, 10_000_000])
    parser.add_argument("--dir", type=Path, default=None, help="where the logs go (default: a temporary folder)")
    args = parser.parse_args()
    work = Path(args.dir or tempfile.mkdtemp(prefix="bench-log-memory-"))
    work.mkdir(parents=True, exist_ok=True)
    exe = [sys.executable, "-m", "gantry_twin"]
    seed = work / "excite" / "log.parquet"
    if not seed.exists():
        subprocess.run([*exe, "excite", "--out", str(work / "excite")], check=True, stdout=subprocess.DEVNULL)
    logs = {}
    for rows in sorted(set(args.rows)):
        logs[rows] = work / f"log-{rows}.parquet"
        if not logs[rows].exists():
            make_log(seed, rows, logs[rows])
    commands = {
        "monitor --log": lambda log, out: [*exe, "monitor", "--log", str(log), "--out", str(out)],
        "identify": lambda log, out: [*exe, "identify", str(log), "--out", str(out)],
    }
    smallest = logs[min(logs)]
    for make in commands.values():  # warm the compiled cache
        peak(make(smallest, work / "warm"))
    print(f"{'command':<16}" + "".join(f"{f'{rows:,} rows':>34}" for rows in logs))
    for name, make in commands.items():
        cells = []
        for rows, log in logs.items():
            code, mb, wall, last = peak(make(log, work / f"out-{name.split()[0]}-{rows}"))
            cells.append(f"exit {code}, {mb:7.0f} MB, {wall:6.1f} s")
            if code:
                print(f"  ({name}, {rows:,} rows: {last[:150]})", file=sys.stderr)
        print(f"{name:<16}" + "".join(f"{c:>34}" for c in cells), flush=True)


if __name__ == "__main__":
    main()
