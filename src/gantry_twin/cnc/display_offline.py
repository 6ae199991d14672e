#!/usr/bin/python3
"""The display program LinuxCNC runs in the twin's offline mode (``[DISPLAY] DISPLAY``): it drives a program.

This file is not imported by the twin. It is copied into a LinuxCNC session's
directory and run by LinuxCNC's launcher under Debian's system Python 3, the
one that has LinuxCNC's ``linuxcnc`` module (a separate program: the twin
itself never loads LinuxCNC's code; docs/linuxcnc.md). It reads its settings
from the INI's ``[GANTRY_TWIN]`` section, written by :mod:`gantry_twin.cnc.session`:

    PROGRAM    the part program to run
    EVENTS     a file of JSON lines this program appends to (flushed per line)
    RECORD     the file the servo-period samples go to (``halsampler -t``)
    TIMEOUT_S  wall seconds the whole program may take
    TWIN_PID   the twin's process: if it ends (even by SIGKILL), the program is stopped, LinuxCNC ends,
               and once the launcher is gone the session's directory ROOT is removed
    ROOT       the session's directory

It resets the estop, turns the machine on, homes every joint, opens the
program, enables HAL's ``sampler`` (the X and Y joint commands at every
servo period), runs the program to its end, waits for the motion to stop,
disables the sampler, drains its FIFO and exits, which ends LinuxCNC.
Every step is bounded in time; an error of LinuxCNC's (a program it
refuses, a limit) is written to EVENTS with LinuxCNC's own text.
"""

import json
import os
import subprocess
import sys
import threading
import time


def bring_up(linuxcnc, stat, command, wait):
    """Estop reset, machine on, every joint homed: what a person does first in LinuxCNC's GUI. ``wait(what,
    done, limit_s)`` polls ``stat`` until ``done()`` (bounded). The tests' live display program uses it too."""
    command.state(linuxcnc.STATE_ESTOP_RESET)
    command.wait_complete(5)
    command.state(linuxcnc.STATE_ON)
    command.wait_complete(5)
    wait("machine on", lambda: stat.task_state == linuxcnc.STATE_ON, 10)
    command.mode(linuxcnc.MODE_MANUAL)
    command.wait_complete(5)
    command.teleop_enable(0)
    command.wait_complete(5)
    command.home(-1)
    command.wait_complete(5)
    wait("homing", lambda: all(stat.homed[j] for j in range(stat.joints)), 60)


class TwinGone(RuntimeError):
    """The twin's process ended: nobody waits for the program any more."""


def main(argv):
    import linuxcnc  # Debian's system Python 3 has it; the twin's environment does not

    ini_path = os.path.abspath(argv[argv.index("-ini") + 1])
    ini = linuxcnc.ini(ini_path)
    program = ini.find("GANTRY_TWIN", "PROGRAM")
    events_path = ini.find("GANTRY_TWIN", "EVENTS")
    record_path = ini.find("GANTRY_TWIN", "RECORD")
    timeout_s = float(ini.find("GANTRY_TWIN", "TIMEOUT_S") or "3600")
    twin_pid = int(ini.find("GANTRY_TWIN", "TWIN_PID") or "0")
    root = ini.find("GANTRY_TWIN", "ROOT")
    events = open(events_path, "a", encoding="utf-8")

    def say(event, **fields):
        events.write(json.dumps({"event": event, "wall_s": time.monotonic(), **fields}) + "\n")
        events.flush()

    stat, command, errors = linuxcnc.stat(), linuxcnc.command(), linuxcnc.error_channel()
    kinds = {
        linuxcnc.NML_ERROR: "error", linuxcnc.OPERATOR_ERROR: "error", linuxcnc.NML_TEXT: "text",
        linuxcnc.OPERATOR_TEXT: "text", linuxcnc.NML_DISPLAY: "display", linuxcnc.OPERATOR_DISPLAY: "display",
    }  # fmt: skip
    failed = []

    def drain_errors():
        while True:
            message = errors.poll()
            if not message:
                return
            kind, text = message
            kind = kinds.get(kind, "text")
            say("message", kind=kind, text=str(text))
            if kind == "error":
                failed.append(str(text))

    def twin_alive():
        try:
            os.kill(twin_pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            pass
        return True

    def wait(what, done, limit_s):
        deadline = time.monotonic() + limit_s
        while time.monotonic() < deadline:
            if twin_pid and not twin_alive():
                raise TwinGone(f"{what}: the twin (pid {twin_pid}) ended")
            stat.poll()
            drain_errors()
            if failed:
                raise RuntimeError(f"{what}: {failed[0]}")
            if done():
                return
            time.sleep(0.005)
        raise RuntimeError(f"{what}: not done within {limit_s:g} s")

    def halcmd(*words):
        return subprocess.run(["halcmd", *words], capture_output=True, text=True, timeout=10, check=True).stdout

    sampler = None
    try:
        wait("LinuxCNC's task", lambda: True, 30)
        bring_up(linuxcnc, stat, command, wait)
        say("homed", joints=stat.joints)
        command.mode(linuxcnc.MODE_AUTO)
        command.wait_complete(5)
        command.set_block_delete(1)  # skip the lines starting with "/", as rs274 -b and the twin's reader
        command.wait_complete(5)
        command.program_open(program)
        command.wait_complete(10)
        wait("opening the program", lambda: True, 1)
        record = open(record_path, "w", encoding="ascii")
        sampler = subprocess.Popen(["halsampler", "-c", "0", "-t"], stdout=subprocess.PIPE, text=True)
        copier = threading.Thread(target=lambda: [record.write(line) for line in sampler.stdout], daemon=True)
        copier.start()
        halcmd("setp", "sampler.0.enable", "1")
        say("started", program=program)
        command.auto(linuxcnc.AUTO_RUN, 0)
        command.wait_complete(10)
        wait("starting the program", lambda: stat.interp_state != linuxcnc.INTERP_IDLE or stat.exec_state, 10)

        def finished():
            if stat.paused:  # M0 / M1: a person would press resume
                command.auto(linuxcnc.AUTO_RESUME)
            return stat.interp_state == linuxcnc.INTERP_IDLE and stat.inpos and stat.queue == 0

        wait("the program", finished, timeout_s)
        halcmd("setp", "sampler.0.enable", "0")
        taken = int(halcmd("getp", "sampler.0.sample-num").strip())
        wait("the sampler's FIFO", lambda: int(halcmd("getp", "sampler.0.curr-depth").strip()) == 0, 10)
        time.sleep(0.05)
        sampler.terminate()
        sampler.wait(10)
        copier.join(10)
        record.close()
        overruns = int(halcmd("getp", "sampler.0.overruns").strip())
        say("finished", samples=taken, overruns=overruns)
        return 0
    except TwinGone as exc:  # nobody reads what is said: LinuxCNC ends, and its directory goes after it
        say("failed", why=str(exc), errors=failed)
        if root:
            subprocess.Popen(
                ["sh", "-c", f"while kill -0 {os.getppid()} 2>/dev/null; do sleep 0.2; done; rm -rf '{root}'"],
                start_new_session=True,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        return 1
    except Exception as exc:  # every failure is said, then LinuxCNC ends
        drain_errors()
        say("failed", why=str(exc), errors=failed)
        return 1
    finally:
        if sampler is not None and sampler.poll() is None:
            sampler.kill()
        try:
            command.state(linuxcnc.STATE_ESTOP)
        except Exception:
            pass
        events.close()


if __name__ == "__main__":
    sys.exit(main(sys.argv))
