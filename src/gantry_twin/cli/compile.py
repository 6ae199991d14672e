"""``gantry-twin compile [--controller NAME ...]``: compile the controllers' loops for this install ahead of the
first run (docs/cli.md, "compile"; docs/performance.md, "Compile")."""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from gantry_twin.cli.common import EXIT_OK, PROG, BadInput, failed

#: The loops ``compile`` makes when no --controller is given: every built-in controller (DRC, DARC and DIARC share
#: one loop, so three names cost one compile).
BUILT_IN = ("pd", "drc", "darc", "diarc")
#: The short run each loop is compiled with: long enough for a run's every kernel (the summary's too), s.
SHORT_RUN = ("duration_s=2", "window_s=[1, 2]", "estimates_window_s=[1, 2]")


def add_arguments(parser: argparse.ArgumentParser, default_scenario: str) -> None:
    parser.add_argument(
        "--controller",
        metavar="NAME",
        action="append",
        help=f"a controller whose loop to compile (repeatable; default: {', '.join(BUILT_IN)})",
    )
    parser.set_defaults(compile_scenario=default_scenario)


def command(args: argparse.Namespace) -> int:
    """Compile (or find cached) each named controller's loop with a short run of the default scenario; exit 0 when
    every loop is ready. An unknown name is BadInput (exit 2); a loop that fails to compile or run, exit 1."""
    from gantry_twin.controllers import available
    from gantry_twin.controllers.base import compiled_step_of
    from gantry_twin.loop.compiling import Ticker, compile_message, expected_compile_s, loop_of
    from gantry_twin.loop.simulate import compiled_available, loop_needs_compiling
    from gantry_twin.numerics.jit import cache_dir
    from gantry_twin.run import run_scenario
    from gantry_twin.scenario import build, load_scenario, resolve_scenario
    from gantry_twin.sweep.engine import compile_lock

    names = list(dict.fromkeys(args.controller or BUILT_IN))
    known = available()
    for name in names:
        if name not in known:
            raise BadInput(f"--controller {name}: unknown controller; available: {', '.join(known)}")
    path = resolve_scenario(args.compile_scenario)
    controllers = {name: build(load_scenario(path, list(SHORT_RUN), name), str(path)).controller for name in names}
    if not compiled_available():
        print(f"{PROG}: MuJoCo's shared library was not found: runs use the Python loop, nothing to compile")
        return EXIT_OK
    loops: dict[object, list[str]] = {}
    for name, controller in controllers.items():
        loops.setdefault(loop_of(controller), []).append(name)
    done = []
    for group in loops.values():
        label, controller = "/".join(group), controllers[group[0]]
        if compiled_step_of(controller) is None:
            print(f"{label}: runs in the Python loop (no compiled step), nothing to compile")
            continue
        with compile_lock():  # a sweep's workers, or another compile, may be compiling it now
            if not loop_needs_compiling(controller):
                print(f"{label}: already compiled for this install")
                continue
            started = time.process_time()
            message = compile_message(f"{PROG} ({label})", expected_compile_s(controller))
            try:
                with Ticker(message), tempfile.TemporaryDirectory(prefix="gantry-twin-compile-") as tmp:
                    for member in group:  # one loop; each controller's run compiles what its summary needs (DIARC's)
                        run_scenario(path, SHORT_RUN, member, out=Path(tmp) / member)
            except Exception as exc:  # a plug-in's step that does not compile, or whose run fails
                return failed(f"{label}: compiling its loop with a short run", exc)
        done.append(f"{label} {time.process_time() - started:.1f} s CPU")
    if done:
        print(f"compiled: {', '.join(done)}; cached in {cache_dir()}")
    return EXIT_OK
