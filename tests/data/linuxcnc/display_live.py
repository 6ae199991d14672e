#!/usr/bin/python3
"""The tests' headless display for LinuxCNC's live mode (``[DISPLAY] DISPLAY``), run by LinuxCNC under Debian's
Python (it has LinuxCNC's ``linuxcnc`` and ``hal`` modules). Settings, in the INI's ``[GANTRY_TWIN_TEST]``:

    PROGRAM    the part program to run (none: only wait, with the machine on, for the estop)
    EVENTS     a file of JSON lines this program appends to (flushed per line)
    WAIT_S     with a PROGRAM: seconds to stay on after it (a fault may come); without: seconds to wait for the estop
    ESTOP      1: press the estop (after the program, if any) before that wait

It waits until HAL's watchdog sees the twin (``watchdog.ok-out``: the twin streams, ok), resets the estop, turns
the machine on, homes, runs the program while it watches LinuxCNC's following error, says what HAL's pins hold,
and exits (LinuxCNC then ends). Every step is bounded in time.
"""

import json
import subprocess
import sys
import time


def main(argv):
    import hal
    import linuxcnc
    from display_offline import bring_up  # the offline display's bring-up, copied beside this file by the tests

    ini = linuxcnc.ini(argv[argv.index("-ini") + 1])
    program = ini.find("GANTRY_TWIN_TEST", "PROGRAM") or ""
    events = open(ini.find("GANTRY_TWIN_TEST", "EVENTS"), "a", encoding="utf-8")
    wait_s = float(ini.find("GANTRY_TWIN_TEST", "WAIT_S") or "0")
    stat, command, errors = linuxcnc.stat(), linuxcnc.command(), linuxcnc.error_channel()
    component = hal.component("gantry-twin-test-display")  # HAL's module reads pins only with a component of its own
    component.ready()
    said = []

    def say(event, **fields):
        events.write(json.dumps({"event": event, "wall_s": time.monotonic(), **fields}) + "\n")
        events.flush()

    def drain():
        while True:
            message = errors.poll()
            if not message:
                return
            said.append(str(message[1]))
            say("message", text=str(message[1]))

    def wait(what, done, limit_s):
        deadline = time.monotonic() + limit_s
        while time.monotonic() < deadline:
            stat.poll()
            drain()
            if done():
                return True
            time.sleep(0.002)
        raise RuntimeError(f"{what}: not done within {limit_s:g} s")

    def halcmd(*words):
        return subprocess.run(["halcmd", *words], capture_output=True, text=True, timeout=10).stdout

    try:
        wait("the twin", lambda: hal.get_value("watchdog.ok-out"), 120)
        say("twin_ready")
        bring_up(linuxcnc, stat, command, wait)
        say("homed")
        if program:
            command.mode(linuxcnc.MODE_AUTO)
            command.wait_complete(5)
            command.program_open(program)
            command.wait_complete(10)
            command.auto(linuxcnc.AUTO_RUN, 0)  # not waited for: the program runs meanwhile
            wait("starting the program", lambda: stat.interp_state != linuxcnc.INTERP_IDLE, 10)
            say("started")
            samples = []  # (x cmd, x fb, LinuxCNC's x following error) mm, read in one go from HAL's pins

            def finished():
                if stat.task_state == linuxcnc.STATE_ESTOP:
                    return True
                if len(samples) < 20000:
                    samples.append([hal.get_value(p) for p in ("joint.0.motor-pos-cmd", "joint.0.motor-pos-fb",
                                                               "joint.0.f-error")])  # fmt: skip
                return stat.interp_state == linuxcnc.INTERP_IDLE and stat.inpos and stat.queue == 0

            wait("the program", finished, 60)
            say("program_done", estop=stat.task_state == linuxcnc.STATE_ESTOP, samples=samples,
                ferror_highmark=[stat.joint[j]["ferror_highmark"] for j in range(2)],
                ferror_limit=[stat.joint[j]["max_ferror"] for j in range(2)])  # fmt: skip
            say("pins", show=halcmd("show", "pin", "joint.0.motor-pos"),
                fb=[float(halcmd("getp", f"joint.{j}.motor-pos-fb")) for j in range(2)],
                cmd=[float(halcmd("getp", f"joint.{j}.motor-pos-cmd")) for j in range(2)])  # fmt: skip
        if ini.find("GANTRY_TWIN_TEST", "ESTOP") == "1":  # the operator's estop: the twin's run ends with it
            command.state(linuxcnc.STATE_ESTOP)
            command.wait_complete(5)
            say("estop_pressed")
        if wait_s > 0:
            try:
                wait("the estop", lambda: stat.task_state == linuxcnc.STATE_ESTOP, wait_s)
            except RuntimeError:
                pass
        say("end", estop=stat.task_state == linuxcnc.STATE_ESTOP, hal=halcmd("show", "pin", "watchdog", "streamer"),
            enable_in=bool(hal.get_value("iocontrol.0.emc-enable-in")), messages=said)  # fmt: skip
        return 0
    except Exception as exc:
        drain()
        say(
            "failed",
            why=str(exc),
            messages=said,
            hal=halcmd("show", "pin", "watchdog", "and2", "streamer", "iocontrol"),
        )
        return 1
    finally:
        events.close()


if __name__ == "__main__":
    sys.exit(main(sys.argv))
