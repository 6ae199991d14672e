"""Run ``gantry-twin`` command lines in child processes and measure them (tests/test_hostile_input.py).

Run as a script with one job per JSON line on stdin (cwd, argv, and the files for the child's stdout and
stderr); it prints one JSON line per job: the child's exit code, wall time and peak RSS. Two modes:

* ``fresh``: each job in a new ``python -m gantry_twin.cli``, start-up included.
* ``fork``: the script imports the CLI once, prints its own start-up (wall time and peak RSS, from
  /proc/self/status VmHWM), then forks one child per job that runs ``cli.main(argv)`` as the console
  script would; a job's line also gives the child's RSS when it started, so that the test can add only
  what the case itself took to the start-up's peak.

Why a script of its own: Linux carries a process's peak RSS across fork and exec (``ru_maxrss``), so a
child started straight from the test process would report the test process's peak; this script's
children start from a small process. Only the standard library is imported (and the CLI in ``fork``).
"""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import threading
import time
import traceback
from pathlib import Path

#: A safety net for the machine should a case regress (e.g. read /dev/zero): a child cannot map more than this.
#: The limit is on address space, about 2 GiB of which the imports reserve; the tests assert on peak RSS.
ADDRESS_SPACE_LIMIT = 4 << 30
#: A hung child is killed after this long and fails its time check; the other jobs go on.
HANG_S = 60
_WRITE = os.O_WRONLY | os.O_CREAT | os.O_TRUNC


def limit_address_space() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE_LIMIT, ADDRESS_SPACE_LIMIT))


def _kib(field: str) -> int:
    """A ``kB`` field of /proc/self/status (VmRSS, VmHWM)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise KeyError(field)


def _forked_child(job: dict) -> None:
    code = 1
    try:
        from gantry_twin.cli import app as cli

        signal.alarm(HANG_S)
        limit_address_space()
        os.chdir(job["cwd"])
        for fd, name, flags in ((0, os.devnull, os.O_RDONLY), (1, job["stdout"], _WRITE), (2, job["stderr"], _WRITE)):
            os.dup2(os.open(name, flags, 0o644), fd)
        start_rss_kib = _kib("VmRSS")
        os.write(job["rss_fd"], f"{start_rss_kib}\n".encode())
        code = cli.main(job["argv"])
    except BaseException:  # noqa: BLE001 -- what an uncaught exception does: a traceback and exit 1
        traceback.print_exc()
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


def _fork(job: dict) -> dict:
    read_end, write_end = os.pipe()
    began = time.perf_counter()
    pid = os.fork()
    if pid == 0:
        os.close(read_end)
        _forked_child({**job, "rss_fd": write_end})
    os.close(write_end)
    with os.fdopen(read_end) as pipe:
        start_rss_kib = int(pipe.read().strip() or 0)
    _, status, usage = os.wait4(pid, 0)
    wall_s = time.perf_counter() - began
    return {
        "code": os.waitstatus_to_exitcode(status),
        "wall_s": wall_s,
        "cpu_s": usage.ru_utime + usage.ru_stime,
        "maxrss_kib": usage.ru_maxrss,
        "start_rss_kib": start_rss_kib,
    }


def _fresh(job: dict) -> dict:
    with open(job["stdout"], "wb") as stdout, open(job["stderr"], "wb") as stderr:
        began = time.perf_counter()
        child = subprocess.Popen(
            [sys.executable, "-m", "gantry_twin.cli", *job["argv"]],
            cwd=job["cwd"],
            stdin=subprocess.DEVNULL,
            stdout=stdout,
            stderr=stderr,
            preexec_fn=limit_address_space,
        )
    killer = threading.Timer(HANG_S, child.kill)
    killer.start()
    try:
        _, status, usage = os.wait4(child.pid, 0)  # reaped here, with its rusage (Popen.wait would drop it)
    finally:
        killer.cancel()
    child.returncode = os.waitstatus_to_exitcode(status)
    return {
        "code": child.returncode,
        "wall_s": time.perf_counter() - began,
        "cpu_s": usage.ru_utime + usage.ru_stime,
        "maxrss_kib": usage.ru_maxrss,
    }


def main() -> None:
    mode = sys.argv[1]
    if mode == "fork":
        started = time.perf_counter()
        from gantry_twin.cli import app as cli  # noqa: F401 -- the imports every child shares

        own = resource.getrusage(resource.RUSAGE_SELF)
        start_up = {"wall_s": time.perf_counter() - started, "cpu_s": own.ru_utime + own.ru_stime}
        print(json.dumps({**start_up, "rss_kib": _kib("VmHWM")}), flush=True)
    for line in sys.stdin:
        job = json.loads(line)
        print(json.dumps(_fork(job) if mode == "fork" else _fresh(job)), flush=True)


if __name__ == "__main__":
    main()
