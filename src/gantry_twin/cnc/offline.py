"""The offline mode: LinuxCNC runs a program headless and its X and Y joint commands are recorded at every servo
period; the twin then tracks them (:mod:`gantry_twin.cnc.reference`). Docs: docs/linuxcnc.md.

The session (:mod:`gantry_twin.cnc.session`) gets a configuration of the
machine (:mod:`gantry_twin.cnc.config`) whose display is
``display_offline.py`` (a program of the twin's that drives LinuxCNC through
its ``linuxcnc`` module under Debian's Python) and whose HAL samples
``joint.N.pos-cmd`` (the joint's own coordinate, without the motor offset
homing may set) into HAL's ``sampler``, read by ``halsampler``. The
program is first read by LinuxCNC's ``rs274`` (:mod:`gantry_twin.cnc.canon`):
a program it refuses ends there, with its message and line.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gantry_twin.cnc.canon import CanonProgram, read_canon
from gantry_twin.cnc.config import HAL_NAME, INI_NAME, CncMachine, hal_text, ini_text
from gantry_twin.cnc.session import LinuxCncError, Session, machine_lock
from gantry_twin.gcode.geometry import Dwell
from gantry_twin.gcode.oracle import link_subroutine_path, subroutine_dirs
from gantry_twin.gcode.program import GcodeError

#: The display program (this package's file, run by LinuxCNC under Debian's Python).
DISPLAY_SCRIPT = Path(__file__).with_name("display_offline.py")
#: Wall seconds a program may take: this many times its length at its feeds (plus its dwells), plus START_S.
TIMEOUT_FACTOR, START_S = 4.0, 60.0


@dataclass(frozen=True)
class CncRecord:
    """What LinuxCNC did with a program: its X and Y commands at every servo period from the program's start
    (t_s (n,) s, q_m (n, 2) m, machine coordinates), the source line motion ran at each (line (n,), 0 where
    none), the servo period, the program's time in LinuxCNC (s, its wall time), LinuxCNC's messages, and the
    canonical moves rs274 read (:class:`CanonProgram`)."""

    t_s: np.ndarray
    q_m: np.ndarray
    line: np.ndarray
    servo_period_s: float
    program_time_s: float
    messages: tuple[str, ...]
    canon: CanonProgram
    machine: CncMachine


def timeout_for(canon: CanonProgram, machine: CncMachine) -> float:
    """A bound on a program's wall time (s): TIMEOUT_FACTOR x its moves at their feeds (rapids at the axes'
    speed) and its dwells, plus START_S for LinuxCNC's start."""
    rapid = min(machine.velocity_mm_s) * 1e-3
    total = 0.0
    for item in canon.items:
        if isinstance(item, Dwell):
            total += item.seconds
        else:
            speed = item.feed_m_s if math.isfinite(item.feed_m_s) and item.feed_m_s > 0 else rapid
            total += item.length_m / min(speed, rapid)
    return TIMEOUT_FACTOR * total + START_S


def run_program(
    program: str | Path,
    machine: CncMachine,
    tool_table: Path | None = None,
    lock_timeout_s: float = 600.0,
    subroutine_path: Sequence[Path] = (),
) -> CncRecord:
    """Run ``program`` in LinuxCNC on ``machine`` and record its commands; a subroutine file it calls is in
    ``subroutine_path``, then beside it, for rs274 and for LinuxCNC (as for the twin's reader).

    :class:`~gantry_twin.gcode.GcodeError` for a program LinuxCNC refuses (its
    message, the file and line); :class:`LinuxCncError` when LinuxCNC cannot
    run or fails otherwise. LinuxCNC is stopped and its traces removed on
    every way out, an interrupt included.
    """
    program = Path(program).resolve()
    canon = read_canon(program, tool_table, subroutine_path)
    timeout_s = timeout_for(canon, machine)
    with machine_lock(lock_timeout_s):
        directory = Session.make_directory()
        with Session(directory, directory / INI_NAME, DISPLAY_SCRIPT.name) as session:
            events, record = directory / "events.jsonl", directory / "record.txt"
            display = directory / DISPLAY_SCRIPT.name
            shutil.copyfile(DISPLAY_SCRIPT, display)
            display.chmod(0o755)
            table = directory / "gantry-twin.tbl"
            if tool_table is not None:
                shutil.copyfile(tool_table, table)
            else:
                table.write_text("")
            settings = {"PROGRAM": str(program), "EVENTS": str(events), "RECORD": str(record),
                        "TIMEOUT_S": f"{timeout_s:.1f}", "TWIN_PID": str(os.getpid()),
                        "ROOT": str(directory.parent)}  # fmt: skip
            searched = link_subroutine_path(directory, subroutine_dirs(program, subroutine_path))
            ini = ini_text(machine, str(display), (HAL_NAME,), {"GANTRY_TWIN": settings}, subroutine_path=searched)
            (directory / INI_NAME).write_text(ini)
            (directory / HAL_NAME).write_text(hal_text(record=True))
            session.start()
            status = session.wait(timeout_s + 60.0)
            said = _events(events)
            return _record(program, said, record, status, session.output(), canon, machine)


def _events(path: Path) -> list[dict]:
    try:
        return [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
    except (OSError, ValueError):
        return []


def _record(program: Path, events: list[dict], record: Path, status: int, output: str, canon, machine) -> CncRecord:
    """The record of a session that ended: its samples, or the error LinuxCNC gave."""
    messages = tuple(e["text"] for e in events if e.get("event") == "message" and e.get("kind") != "error")
    failed = next((e for e in events if e.get("event") == "failed"), None)
    finished = next((e for e in events if e.get("event") == "finished"), None)
    if failed is not None:
        errors = failed.get("errors") or []
        if errors:
            raise _program_error(program, errors[0])
        raise LinuxCncError(f"LinuxCNC: {failed.get('why')}")
    if finished is None:
        last = output.strip().splitlines()[-1] if output.strip() else f"exit status {status}"
        raise LinuxCncError(f"LinuxCNC ended before the program did ({last})")
    if finished.get("overruns"):
        raise LinuxCncError(f"LinuxCNC's sampler overran {finished['overruns']} times: samples were lost")
    rows = np.loadtxt(record, dtype=float, ndmin=2)
    if rows.shape[0] < 2 or rows.shape[1] < 4:
        raise LinuxCncError(f"LinuxCNC's sampler recorded {rows.shape[0]} samples of the program")
    tags = rows[:, 0].astype(np.int64)
    if np.any(np.diff(tags) != 1):
        gap = int(np.flatnonzero(np.diff(tags) != 1)[0])
        raise LinuxCncError(f"LinuxCNC's sampler lost samples after sample {tags[gap]}")
    rows = _motion(rows)
    period = machine.servo_period_s
    started = next(e["wall_s"] for e in events if e.get("event") == "started")
    return CncRecord(
        t_s=np.arange(len(rows)) * period,
        q_m=rows[:, 1:3] * 1e-3,
        line=rows[:, 3].astype(np.int64),
        servo_period_s=period,
        program_time_s=float(finished["wall_s"] - started),
        messages=messages,
        canon=canon,
        machine=machine,
    )


def _motion(rows: np.ndarray) -> np.ndarray:
    """The samples from the one before the first motion to the one after the last: the standstill before the
    program starts moving and after it stops depends on when the sampler was switched, not on the program (a
    program that never moves XY: its first two samples)."""
    moved = np.flatnonzero(np.any(np.diff(rows[:, 1:3], axis=0) != 0.0, axis=1))
    if moved.size == 0:
        return rows[:2]
    return rows[moved[0] : min(moved[-1] + 2, len(rows)) + 1]


def _program_error(program: Path, text: str) -> GcodeError:
    """LinuxCNC's error as the twin's one line: ``FILE:LINE: LinuxCNC: its message``."""
    line = 0
    words = text.replace("\n", " ").split()
    if "line" in words:
        try:
            line = int(words[words.index("line") + 1].rstrip(":"))
        except (ValueError, IndexError):
            line = 0
    return GcodeError(str(program), line, "LinuxCNC", " ".join(words))
