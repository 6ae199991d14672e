"""SIGTERM and SIGHUP stop ``gantry-twin run`` as Ctrl-C does: no stray file, no stray process.

Ten runs in child processes, each stopped at a random point (seeded) of one phase: while the loop compiles,
while it simulates and writes the trace, anywhere from the start, with --serve-web running, and while
--serve-web keeps serving the finished run. Each child has 60 s to end. The cases are independent (each its own
directory, cache and child; each waits for its own phase before its own delay), so they run side by side: the test
takes about the time of its longest case (some 15 s on 2 cores), not the sum of all ten.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc to find child processes"),
]

SRC = Path(__file__).resolve().parents[1] / "src"
RUN_FILES = {"summary.json", "scenario.yaml", "trace.parquet", "run_info.json", "plots"}
COMPILING = "compiling the 0.2 ms loop"


def _parents() -> dict[int, int]:
    """pid -> parent pid of every process now."""
    out = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            out[int(entry.name)] = int(fields[1])
    return out


def descendants(pid: int) -> set[int]:
    parents, found, todo = _parents(), set(), [pid]
    while todo:
        parent = todo.pop()
        children = {p for p, pp in parents.items() if pp == parent} - found
        found |= children
        todo.extend(children)
    return found


def running(pid: int) -> bool:
    """True if the process exists and is not a zombie."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def wait_until(condition: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


def part_files(where: Path) -> list[Path]:
    return [p for p in where.rglob("*") if p.name.endswith(".part")]


# (phase, extra arguments, signal, marker (what to wait for before the random delay), delay range s)
CASES = [
    ("compiling", [], signal.SIGTERM, "notice", (0.0, 2.0)),
    ("compiling", [], signal.SIGHUP, "notice", (0.0, 2.0)),
    ("simulating", [], signal.SIGTERM, "part", (0.0, 3.0)),
    ("simulating", [], signal.SIGTERM, "part", (0.0, 3.0)),
    ("simulating", [], signal.SIGHUP, "part", (0.0, 3.0)),
    ("anywhere", [], signal.SIGTERM, "start", (0.0, 12.0)),
    ("anywhere", ["--set", "outputs.trace_stride=3"], signal.SIGTERM, "start", (0.0, 12.0)),
    ("serving during the run", ["--serve-web"], signal.SIGTERM, "viewer", (0.0, 3.0)),
    ("serving during the run", ["--serve-web"], signal.SIGHUP, "viewer", (0.0, 3.0)),
    # 1 s simulated, not 60: the case is about the run once it has finished; how long it ran does not matter.
    ("serving the finished run", ["--serve-web", "--set", "duration_s=1"], signal.SIGTERM, "still serving", (0.0, 0.5)),
]
#: Cases running at once: all of them (ten children of ~0.3 GB; most of each case is start-up and waiting).
AT_ONCE = len(CASES)


def reached(marker: str, work: Path) -> bool:
    """Whether the child in ``work`` has reached the point a case waits for."""
    if marker == "start":
        return True
    if marker == "notice":
        return COMPILING in (work / "stderr.txt").read_text()
    if marker == "part":
        return (work / "out").exists() and bool(part_files(work / "out"))
    text = (work / "stdout.txt").read_text()
    return ("Rerun web viewer:" if marker == "viewer" else "Still serving") in text


def stop_one(work: Path, case: tuple, delay_s: float, compiled_cache: str | None) -> None:
    """Run one case in ``work``: start the child, wait for its marker and ``delay_s``, send the signal, check."""
    phase, extra, signum, marker, _ = case
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    env.pop("NUMBA_CACHE_DIR", None)
    cache = str(work / "cache") if marker == "notice" else compiled_cache  # a fresh cache compiles the loop
    if cache:
        env["NUMBA_CACHE_DIR"] = cache
    command = [sys.executable, "-m", "gantry_twin.cli", "run", "--set", "duration_s=60", "--no-progress", "--out=out"]
    with (work / "stdout.txt").open("w") as out_file, (work / "stderr.txt").open("w") as err_file:
        child = subprocess.Popen([*command, *extra], cwd=work, env=env, stdout=out_file, stderr=err_file)
    try:
        wait_until(lambda: reached(marker, work) or child.poll() is not None, 120.0, f"{marker} ({phase})")
        assert child.poll() is None, f"{phase}: ended before the signal: {(work / 'stderr.txt').read_text()}"
        time.sleep(delay_s)
        below = descendants(child.pid)
        child.send_signal(signum)
        code = child.wait(timeout=60)
    finally:
        if child.poll() is None:
            child.kill()
    label = f"{phase}, {signal.Signals(signum).name} after {delay_s:.2f} s"
    err = (work / "stderr.txt").read_text()
    assert "Traceback" not in err, (label, err)
    out = work / "out"
    if phase == "serving the finished run" or (code == 0 and (out / "summary.json").exists()):
        assert code == 0, (label, err)  # the run had finished: it stays, complete
        assert {p.name for p in out.iterdir()} == RUN_FILES, label
        assert json.loads((out / "summary.json").read_text())["status"] == "ok", label
    elif code == -signum:
        # Only "anywhere" may stop the child during Python's start-up and imports, before main() installs the
        # handlers: the signal's default action ends it (a shell reports the same 128 + N), with nothing written.
        assert phase == "anywhere" and not err.strip() and not out.exists(), (label, code, err)
    else:
        assert code == 128 + signum, (label, code, err)
        assert err.strip().splitlines()[-1] == f"gantry-twin: interrupted ({signal.Signals(signum).name})", label
        assert not out.exists(), (label, sorted(p.name for p in out.iterdir()))
    assert not part_files(work), (label, part_files(work))
    stray = {p.name for p in work.iterdir()} - {"stdout.txt", "stderr.txt", "out", "cache"}
    assert not stray, (label, stray)
    wait_until(lambda: not any(running(pid) for pid in below), 10.0, f"the child processes to end ({label})")


def test_stop_signals_leave_no_stray_file_and_no_stray_process(tmp_path):
    rng = random.Random(12)
    delays = [rng.uniform(*case[4]) for case in CASES]  # drawn in case order, as one at a time would draw them
    cache = os.environ.get("NUMBA_CACHE_DIR")
    for i in range(len(CASES)):
        (tmp_path / f"case{i}").mkdir()
    with ThreadPoolExecutor(AT_ONCE) as pool:  # every case runs to its end (its child stopped) before the pool closes
        done = [pool.submit(stop_one, tmp_path / f"case{i}", case, delays[i], cache) for i, case in enumerate(CASES)]
    for future in done:
        future.result()  # the first failing case's AssertionError
