"""LinuxCNC's planner beside the twin's own, on the shipped programs, and the cost of the offline mode.

    PYTHONPATH=src python benchmarks/bench_linuxcnc.py [--closed-loop] [--programs bracket circle ...]

Needs Debian's ``linuxcnc-uspace`` (docs/linuxcnc.md). For each program in
``programs/``, with the same limits (the twin's machine: LinuxCNC's INI
from ``gantry-twin linuxcnc config``):

- program time: LinuxCNC's recorded commands (first to last motion) and the
  twin's plan (``gantry_twin.gcode.planner``);
- each planner's largest deviation of its *command* from the programmed path
  (the part error of the reference itself, against rs274's canonical moves
  for LinuxCNC and the twin's reader's moves for the twin);
- the LinuxCNC phase of the offline mode: wall time and CPU time (this
  process, LinuxCNC's processes and HAL's tools, all reaped here as a child
  subreaper, every thread counted) over the program time;
- with ``--closed-loop``: ``gantry-twin run PROGRAM`` and ``... --cnc linuxcnc``
  (DIARC on the rig plant): the part error's max and rms, and the whole
  offline run's wall and CPU time over the program time.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gantry_twin.cnc.config import twin_machine
from gantry_twin.cnc.offline import run_program
from gantry_twin.cnc.reference import CncPath
from gantry_twin.gcode.part_error import part_error
from gantry_twin.gcode.planner import plan_program
from gantry_twin.gcode.reader import read_program

ROOT = Path(__file__).resolve().parents[1]
PR_SET_CHILD_SUBREAPER = 36


def cpu_s() -> float:
    """CPU seconds of this process and of every child reaped so far (user + system)."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def reap() -> None:
    """Reap the orphans reparented here (LinuxCNC's servers start sessions of their own)."""
    while True:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            time.sleep(0.05)


def planners(name: str) -> dict:
    program = ROOT / "programs" / f"{name}.ngc"
    cpu0, wall0 = cpu_s(), time.perf_counter()
    record = run_program(program, twin_machine())
    reap()
    wall, cpu = time.perf_counter() - wall0, cpu_s() - cpu0
    path = CncPath(record)
    lc = part_error(path, record.t_s, record.q_m)
    plan = plan_program(read_program(program))
    t = np.arange(0.0, plan.duration_s, 1e-3)
    tw = part_error(plan, t, plan.sample(t).q_m)
    return {
        "program": name, "lc_time_s": float(record.t_s[-1]), "twin_time_s": plan.duration_s,
        "lc_dev_um": 1e6 * lc.max_m, "twin_dev_um": 1e6 * tw.max_m,
        "lc_wall_per_s": wall / float(record.t_s[-1]), "lc_cpu_per_s": cpu / float(record.t_s[-1]),
    }  # fmt: skip


def closed_loop(name: str, cnc: bool) -> dict:
    program = ROOT / "programs" / f"{name}.ngc"
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        command = [sys.executable, "-m", "gantry_twin", "run", str(program), "--out", str(out), "--no-progress"]
        command += ["--cnc", "linuxcnc"] if cnc else []
        cpu0, wall0 = cpu_s(), time.perf_counter()
        subprocess.run(command, check=True, capture_output=True, cwd=ROOT)
        reap()
        wall, cpu = time.perf_counter() - wall0, cpu_s() - cpu0
        summary = json.loads((out / "summary.json").read_text())
    part = summary["part_error"]
    return {"max_um": part["max_um"], "rms_um": part["rms_um"], "cycle_s": part["cycle_time_s"],
            "wall_s": wall, "cpu_s": cpu}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--programs", nargs="+", default=sorted(p.stem for p in (ROOT / "programs").glob("*.ngc")))
    parser.add_argument("--closed-loop", action="store_true", help="also run both in the closed loop (DIARC)")
    args = parser.parse_args()
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)
    print(f"load average at start: {os.getloadavg()[0]:.2f}; {os.cpu_count()} cores")
    print(f"{'program':20s} {'time LinuxCNC':>13s} {'time twin':>10s} {'cmd dev LinuxCNC':>16s} "
          f"{'cmd dev twin':>12s} {'LinuxCNC wall/s':>15s} {'CPU/s':>6s}")  # fmt: skip
    rows = []
    for name in args.programs:
        r = planners(name)
        rows.append(r)
        print(f"{name:20s} {r['lc_time_s']:11.3f} s {r['twin_time_s']:8.3f} s {r['lc_dev_um']:13.2f} um "
              f"{r['twin_dev_um']:9.2f} um {r['lc_wall_per_s']:15.3f} {r['lc_cpu_per_s']:6.3f}")  # fmt: skip
    if args.closed_loop:
        print(f"\n{'program':20s} {'part max/rms LinuxCNC':>22s} {'part max/rms twin':>20s} "
              f"{'offline wall/s':>14s} {'CPU/s':>6s}")  # fmt: skip
        for r in rows:
            lc, tw = closed_loop(r["program"], True), closed_loop(r["program"], False)
            print(
                f"{r['program']:20s} {lc['max_um']:9.1f} / {lc['rms_um']:5.2f} um {tw['max_um']:8.1f} / "
                f"{tw['rms_um']:5.2f} um {lc['wall_s'] / lc['cycle_s']:14.3f} {lc['cpu_s'] / lc['cycle_s']:6.3f}"
            )
    print(f"load average at end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
