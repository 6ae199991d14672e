"""``gantry-twin fmu check FILE``: a controller FMU checked against the variable convention, its mapping printed,
before any run; ``gantry-twin fmu export`` (the plant as an FMU, :mod:`gantry_twin.cli.fmu_export`); and
``--log-fmu-variables`` of ``run`` and ``monitor`` (docs/fmi.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gantry_twin.cli import fmu_export
from gantry_twin.cli.common import EXIT_OK, PROG, BadInput
from gantry_twin.fmi.description import INPUT_SIGNALS, OUTPUT_SIGNALS, FmuError, read_controller
from gantry_twin.fmi.instance import trial_start
from gantry_twin.scenario import Scenario
from gantry_twin.settings import shorten


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``fmu`` group of subcommands."""
    parser = sub.add_parser("fmu", help="FMI: check a controller FMU, export the plant as an FMU (docs/fmi.md)")
    group = parser.add_subparsers(
        dest="fmu_command", required=True, metavar="{check,export}", parser_class=type(parser)
    )
    check = group.add_parser(
        "check", help="check a controller FMU against the variable convention and print its mapping, before any run"
    )
    check.add_argument("file", type=Path, help="the .fmu file (FMI 2.0 co-simulation)")
    check.add_argument(
        "--map",
        dest="variables",
        action="append",
        default=[],
        metavar="VARIABLE=SIGNAL",
        help=f"bind an FMU variable to a signal ({', '.join((*INPUT_SIGNALS, *OUTPUT_SIGNALS))}), "
        "as controller.options.variables does",
    )
    add_log_argument(check)
    check.set_defaults(func=check_command)
    fmu_export.add_parser(group)


def add_log_argument(parser: argparse.ArgumentParser) -> None:
    """``--log-fmu-variables NAMES``: FMU variables into the trace (``run``, ``monitor``, ``fmu check``)."""
    parser.add_argument(
        "--log-fmu-variables",
        metavar="NAMES",
        type=_names,
        default=(),
        help="comma-separated variables of a controller FMU recorded every sample into the trace "
        "(columns fmu_<name>), added to controller.options.log_variables",
    )


def add_limit_arguments(parser: argparse.ArgumentParser) -> None:
    """``--fmu-timeout S`` and ``--fmu-memory MIB``: a controller FMU's limits (``run``, ``monitor``)."""
    from gantry_twin.fmi.controller import LIMITS

    low, high = LIMITS["call_timeout_s"]
    parser.add_argument(
        "--fmu-timeout",
        metavar="S",
        type=_number_in(low, high, "s"),
        help=f"wall time a controller FMU's calls of one sample may take before the run fails ({low:g} to "
        f"{high:g} s; default 10; controller.options.call_timeout_s)",
    )
    low, high = LIMITS["memory_limit_mb"]
    parser.add_argument(
        "--fmu-memory",
        metavar="MIB",
        type=_number_in(low, high, "MiB"),
        help=f"resident memory of the process hosting a controller FMU before the run fails ({low:.10g} to {high:.10g} "
        "MiB; default 2048; controller.options.memory_limit_mb)",
    )


def _number_in(low: float, high: float, unit: str):  # noqa: ANN202 -- an argparse type
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number of {unit}, got {text!r}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be in [{low:.10g}, {high:.10g}] {unit}, got {text}")
        return value

    return parse


def with_limits(scenario: Scenario, timeout_s: float | None, memory_mib: float | None) -> Scenario:
    """The scenario with ``--fmu-timeout`` and ``--fmu-memory`` in its FMU controller's options; BadInput if one is
    given and its controller is not ``fmu``."""
    given = {"call_timeout_s": timeout_s, "memory_limit_mb": memory_mib}
    given = {name: value for name, value in given.items() if value is not None}
    if not given:
        return scenario
    controller = scenario.controller
    if controller.name != "fmu":
        flags = " and ".join(
            f for f, v in (("--fmu-timeout", timeout_s), ("--fmu-memory", memory_mib)) if v is not None
        )
        raise BadInput(f"{flags}: the controller is {controller.name}, not fmu (docs/fmi.md)")
    options = {**controller.options, **given}
    return scenario.model_copy(update={"controller": controller.model_copy(update={"options": options})})


def _names(text: str) -> tuple[str, ...]:
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if not names:
        raise argparse.ArgumentTypeError(f"expected comma-separated variable names, got {text!r}")
    return names


def with_logged_variables(scenario: Scenario, names: tuple[str, ...]) -> Scenario:
    """The scenario with ``names`` added to its FMU controller's ``log_variables``; BadInput if its controller is
    not ``fmu``."""
    if not names:
        return scenario
    controller = scenario.controller
    if controller.name != "fmu":
        raise BadInput(f"--log-fmu-variables: the controller is {controller.name}, not fmu (docs/fmi.md)")
    given = controller.options.get("log_variables") or []
    given = list(given) if isinstance(given, list | tuple) else [given]
    logged = [*given, *(n for n in names if n not in given)]
    options = {**controller.options, "log_variables": logged}
    return scenario.model_copy(update={"controller": controller.model_copy(update={"options": options})})


def python_loop_note(controller: object, samples: int, wall_time_s: float) -> str | None:
    """The note ``run`` prints after a run of an FMU that needs Python: it ran on the Python loop, and its cost per
    sample; None for any other controller."""
    from gantry_twin.fmi.controller import PythonFmuController

    if not isinstance(controller, PythonFmuController) or samples <= 0:
        return None
    tool = controller.fmu.generation_tool or "pythonfmu"
    return (
        f"{PROG}: note: {controller.fmu.path.name} needs Python (built with {tool}): it ran on the Python loop, "
        f"{wall_time_s / samples * 1e6:.0f} us per sample ({samples} samples in "
        f"{wall_time_s:.1f} s; a native FMU runs in the compiled loop, docs/fmi.md)"
    )


def check_command(args: argparse.Namespace) -> int:
    """Read and check the FMU, start one instance (unpack, load, instantiate, initialise, terminate), print the
    binding; exit 2 with one line if it cannot run as a controller."""
    variables = {}
    for item in args.variables:
        name, sep, signal = item.partition("=")
        if not sep or not name or not signal:
            raise BadInput(f"--map {shorten(item)}: expected VARIABLE=SIGNAL, e.g. pos_x=x_m")
        variables[name] = signal
    try:
        fmu = read_controller(args.file, variables, None, args.log_fmu_variables)
        trial_start(fmu)
    except FmuError as exc:
        raise BadInput(str(exc)) from None
    how = (
        "needs Python (built with pythonfmu): runs on the Python loop"
        if fmu.needs_python
        else "native: runs in the compiled loop"
    )
    print(f"{fmu.path}: FMI {fmu.fmi_version} co-simulation, model {fmu.model_identifier!r}, {how}")
    if fmu.generation_tool:
        print(f"  generated by {fmu.generation_tool}")
    print("\n".join(fmu.mapping_lines()))
    for name, start in fmu.settable:
        print(f"  settable parameter {name!r} (start {start}): controller.options.parameters.{name}")
    print(f"{PROG}: {args.file}: ok, runs as controller: {{name: fmu, options: {{fmu: {args.file}}}}}", file=sys.stderr)
    return EXIT_OK
