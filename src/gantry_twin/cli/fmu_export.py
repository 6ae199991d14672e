"""``gantry-twin fmu export [--plant rig|paper] [--out FILE] [--payload-kg KG] [--set NAME=VALUE ...] [--python]``:
the twin's plant as an FMI 2.0 co-simulation FMU, native (C, MuJoCo's library inside) or with ``--python``
pythonfmu's (docs/fmi.md, "The plant as an FMU"; docs/cli.md).

:func:`add_parser` adds ``export`` to the ``fmu`` group; :func:`command` runs it (exit 0, or
:class:`~gantry_twin.cli.common.BadInput`: exit 2, one line, nothing written).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from gantry_twin.cli.common import EXIT_OK, PROG, BadInput, number_type
from gantry_twin.fmi.plant_export import export_plant
from gantry_twin.fmi.plant_native import NoCompilerError
from gantry_twin.outputs.files import NotRegularFileError
from gantry_twin.plant.model import DEFAULT_PLANT_MODEL, PAYLOAD_MAX_KG, PLANT_MODELS, PLANT_WORDS

#: Where the FMU goes when --out names no file.
DEFAULT_OUT = "gantry_{plant}_plant.fmu"


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add ``export`` to the ``fmu`` group's subparsers; its ``func`` is :func:`command`."""
    parser = subparsers.add_parser(
        "export",
        help="write the twin's plant as an FMI 2.0 co-simulation FMU (native: compiled here with cc, MuJoCo inside)",
        description="Write the twin's plant as an FMI 2.0 co-simulation FMU: inputs u_x_v, u_y_v, d_x_v, d_y_v (V), "
        "outputs the encoder (x_m, y_m, dx_m_s, dy_m_s) and the true state (x_true_m, ...), communication steps of "
        "whole 0.2 ms samples (docs/fmi.md). Native by default: C compiled here with the machine's C compiler ($CC "
        "or cc), MuJoCo's library inside; it needs nothing but Linux x86-64 where it runs.",
    )
    parser.add_argument(
        "--plant",
        choices=tuple(PLANT_MODELS),
        default=DEFAULT_PLANT_MODEL,
        help=f"the machine: rig (models/rig.xml, the default) or paper (models/gantry.xml, the paper's "
        f"{PLANT_WORDS['paper']} model)",
    )
    parser.add_argument(
        "--out",
        metavar="FILE",
        type=Path,
        help=f"the .fmu file to write (default: {DEFAULT_OUT.format(plant='PLANT')})",
    )
    parser.add_argument(
        "--payload-kg",
        type=number_type("--payload-kg", f"a mass in [0, {PAYLOAD_MAX_KG}] kg", 0.0, PAYLOAD_MAX_KG),
        default=0.0,
        help="the payload parameter's default, kg (payload.mass_kg; 0 by default)",
    )
    parser.add_argument(
        "--set",
        dest="parameters",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="another parameter's default: friction.<x|y>.<fc_n|sigma2_ns_m|fs_n|vs_m_s|sigma0_n_m|sigma1_ns_m> "
        "(the last four on the rig's LuGre plant only), start.<x_m|y_m|dx_m_s|dy_m_s>; repeatable",
    )
    parser.add_argument(
        "--python",
        action="store_true",
        help="build with pythonfmu instead (no C compiler needed here; the FMU needs a Python with this gantry-twin "
        "where it runs)",
    )
    parser.set_defaults(func=command)
    return parser


def parameter_values(items: list[str]) -> dict[str, float]:
    """``NAME=VALUE`` strings as {name: number} (BadInput naming the item that is not one)."""
    values = {}
    for item in items:
        name, sep, text = item.partition("=")
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not sep or not name.strip() or not math.isfinite(value):
            raise BadInput(f"--set {item!r}: expected NAME=VALUE with a finite number, e.g. friction.x.fc_n=7.0")
        values[name.strip()] = value
    return values


def command(args: argparse.Namespace) -> int:
    """Run ``fmu export``: write the FMU, print what it is and what it needs."""
    out = args.out if args.out is not None else Path(DEFAULT_OUT.format(plant=args.plant))
    parameters = parameter_values(args.parameters)
    try:
        exported = export_plant(out, args.plant, args.payload_kg, parameters, python=args.python)
    except NoCompilerError as exc:
        raise BadInput(f"{exc}: the native plant FMU is compiled here; --python builds the pythonfmu one") from None
    except NotRegularFileError as exc:
        raise BadInput(f"--out {out}: {exc.strerror} (give the .fmu file's name)") from None
    except OSError as exc:
        raise BadInput(f"--out {out}: cannot write there ({exc.strerror or exc})") from None
    except ValueError as exc:
        raise BadInput(f"--set {str(exc).splitlines()[0]}") from None
    machine = f"{PLANT_WORDS[args.plant]} plant (models/{PLANT_MODELS[args.plant]})"
    step_ms = exported.sample_period_s * 1e3
    kind = "pythonfmu" if args.python else "native"
    print(
        f"wrote {exported.path}: {kind} FMI 2.0 co-simulation FMU of the {machine}; steps: whole {step_ms:g} ms samples"
    )
    print(f"parameters: {', '.join(f'{k}={v:g}' for k, v in exported.parameters.items())}")
    print(f"the FMU {exported.requirement}")
    return EXIT_OK


if __name__ == "__main__":  # python -m gantry_twin.cli.fmu_export ...: the subcommand alone, until `fmu` wires it
    _parser = argparse.ArgumentParser(prog=f"{PROG} fmu")
    add_parser(_parser.add_subparsers(dest="fmu_command", required=True))
    _args = _parser.parse_args(sys.argv[1:])
    try:
        sys.exit(_args.func(_args))
    except BadInput as _exc:
        print(f"{PROG}: error: {_exc}", file=sys.stderr)
        sys.exit(2)
