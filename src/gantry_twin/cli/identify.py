"""``gantry-twin identify LOG [LOG...] --out DIR [--friction coulomb|lugre]`` (docs/logs.md).

coulomb: M, B, Af, dN (:mod:`gantry_twin.sysid.identify`); lugre: those, then each
axis' LuGre parameters (:mod:`gantry_twin.sysid.lugre`). Writes
DIR/identified.json, DIR/plant.xml (the masses, B and Af), DIR/plant.yaml
(a scenario's ``plant`` section: the file and, for lugre, the friction),
DIR/fit_report.md and its figures (the logged commands replayed through the
identified plant).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

import yaml

from gantry_twin.cli.common import BadInput, writable_out
from gantry_twin.outputs.files import atomic_write_text
from gantry_twin.plant.model import AXES, Plant
from gantry_twin.sysid.identify import Identified, IdentifySettings, UnphysicalFit, identify, plant_xml
from gantry_twin.sysid.logs import Log, check_sample_period, read_log
from gantry_twin.sysid.lugre import LuGreFit, identify_lugre
from gantry_twin.sysid.replay import WINDOW_S, Replay, replay, write_figures

IDENTIFIED_FILE = "identified.json"
PLANT_FILE = "plant.xml"
SCENARIO_FILE = "plant.yaml"
REPORT_FILE = "fit_report.md"
#: The friction models ``--friction`` names.
FRICTION_MODELS = ("coulomb", "lugre")
#: Most rows identify takes over all its logs: the regression, the LuGre stages and the fit report's replay
#: hold every row (about 0.4 KB a row: 1 000 000 rows, 200 s at 5 kHz, peaked at 0.8 GB; docs/logs.md).
#: An excitation is 20-30 s.
ROWS_MAX = 1_000_000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("logs", nargs="+", metavar="LOG", help="log files (parquet or CSV, docs/logs.md)")
    parser.add_argument("--out", metavar="DIR", type=Path, required=True, help="output directory")
    parser.add_argument(
        "--friction", choices=FRICTION_MODELS, default="coulomb", help="friction model to identify (default coulomb)"
    )
    parser.add_argument(
        "--filter-hz", type=float, default=IdentifySettings.filter_hz[0], help="Hf's natural frequency, Hz"
    )
    parser.add_argument("--window-s", type=float, default=WINDOW_S, help="replay window of the fit report, s")


def command(args: argparse.Namespace) -> int:
    """``gantry-twin identify``: exit 0; 2 with one line on stderr (BadInput) for a bad log or option, an --out that
    cannot be written (checked first), or logs that cannot identify this machine's model (a fit no machine of this
    kind has: a mass <= 0, a negative damping or friction; the line says what the logs would need): nothing is
    written."""
    try:  # the range is IdentifySettings.filter_hz's, declared once
        settings = IdentifySettings(filter_hz=(args.filter_hz, args.filter_hz))
    except ValueError as exc:
        raise BadInput("--filter-hz: " + str(exc).split(": ", 1)[-1]) from None
    if not (0.0 < args.window_s <= 3600.0):
        raise BadInput(f"--window-s: must be in (0, 3600] s, got {args.window_s:g}")
    out: Path = args.out
    with writable_out(out):  # before any log is read; removed again, empty, if the logs are refused
        try:
            logs = read_logs(args.logs)
            machine_s = Plant().timestep_s
            for log in logs:  # a log at its own period is taken; t_s in ms or us (1000x, 10^6x the machine's) is not
                check_sample_period(log.path, log.sample_period_s, machine_s, exact=False)
            result = identify(logs, settings)
            lugre = identify_lugre(logs, result) if args.friction == "lugre" else None
            note = "gantry-twin identify from " + ", ".join(str(p) for p in args.logs)
            xml = plant_xml(result.theta, note)
        except UnphysicalFit as exc:
            raise BadInput(f"{', '.join(str(p) for p in args.logs)}: {exc}") from None
        except ValueError as exc:  # LogError included
            raise BadInput(str(exc).splitlines()[0]) from None
        try:
            atomic_write_text(out / PLANT_FILE, xml)
            plant = Plant(model_path=out / PLANT_FILE, friction=None if lugre is None else lugre.friction())
            replays = [replay(plant, log, args.window_s) for log in logs]
            figures = write_figures(replays, out)
            data = identified_json(result, lugre, logs, replays, figures)
            atomic_write_text(out / IDENTIFIED_FILE, json.dumps(data, indent=2) + "\n")
            atomic_write_text(out / SCENARIO_FILE, yaml.safe_dump(data["scenario"], sort_keys=False))
            atomic_write_text(out / REPORT_FILE, fit_markdown(data))
        except OSError as exc:
            raise BadInput(f"--out {out}: cannot write there ({exc.strerror or exc})") from None
    print(format_identified(data, out))
    return 0


def read_logs(paths: Sequence[str]) -> list[Log]:
    """The logs, each read whole within what ROWS_MAX leaves (LogError past it, naming the log and the range)."""
    logs: list[Log] = []
    timestep_s = Plant().timestep_s
    for path in paths:
        left = ROWS_MAX - sum(log.samples for log in logs)
        why = (
            f"identify holds its logs whole: {ROWS_MAX} rows in all, {ROWS_MAX * timestep_s:g} s at the machine's "
            f"{timestep_s * 1e3:g} ms"
        )
        logs.append(read_log(path, max_rows=max(left, 0), reader=why + (", with the logs before it" if logs else "")))
    return logs


def scenario_plant(lugre: LuGreFit | None) -> dict[str, object]:
    """A scenario's ``plant`` section for the identified plant (paths relative to DIR)."""
    if lugre is None:
        return {"file": PLANT_FILE}
    friction = {"model": "lugre"}
    for axis, p in zip(AXES, lugre.axes, strict=True):
        friction[axis] = {name: float(value) for name, value in p._asdict().items()}
    return {"file": PLANT_FILE, "friction": friction}


def identified_json(
    result: Identified,
    lugre: LuGreFit | None,
    logs: Sequence[Log],
    replays: Sequence[Replay],
    figures: Sequence[str],
) -> dict[str, object]:
    """identified.json's content (docs/logs.md)."""
    data: dict[str, object] = {"parameters": result.parameters(), "friction": "coulomb" if lugre is None else "lugre"}
    if lugre is not None:
        data["lugre"] = lugre.parameters()
        data["lugre_ci95_note"] = lugre.ci_note
        data["lugre_samples"] = {"velocity_bins": dict(zip(AXES, lugre.bins, strict=True)), "reversals": lugre.windows}
    data |= {
        "plant_file": PLANT_FILE,
        "scenario_file": SCENARIO_FILE,
        "scenario": {"plant": scenario_plant(lugre)},
        "logs": [
            {
                "path": log.path,
                "samples": log.samples,
                "sample_period_s": log.sample_period_s,
                "duration_s": log.duration_s,
            }
            for log in logs
        ],
        "samples_used": dict(zip(AXES, result.samples_used, strict=True)),
        "regression_residual_rms_v": dict(zip(AXES, result.residual_rms_v, strict=True)),
        "settings": asdict(result.settings),
        "fit": [
            {"path": r.path, "window_s": r.window_s, "rms_um": r.rms_um(), "max_um": r.max_um(), "figure": f}
            for r, f in zip(replays, figures, strict=True)
        ],
    }
    return data


def _ci(ci: list[float] | None) -> str:
    return "null" if ci is None else f"[{ci[0]:.6g}, {ci[1]:.6g}]"


def format_identified(data: dict, out: Path) -> str:
    lines = ["parameter        value        ci95                      unit"]
    for name, p in data["parameters"].items():
        lines.append(f"  {name:<4} {p['value']:14.6g}  {_ci(p['ci95'])}  {p['unit']}")
    for axis, params in data.get("lugre", {}).items():
        for name, p in params.items():
            lines.append(f"  {axis} {name:<12} {p['value']:14.6g}  {_ci(p['ci95'])}  {p['unit']}")
    for f in data["fit"]:
        rms = ", ".join(f"{a} {v:.3g}" for a, v in f["rms_um"].items())
        lines.append(f"replay of {Path(f['path']).name} in {f['window_s']:g} s windows: residual rms {rms} um")
    files = [IDENTIFIED_FILE, PLANT_FILE, SCENARIO_FILE, REPORT_FILE, *(f["figure"] for f in data["fit"])]
    lines.append(f"results in {out}/ ({', '.join(files)})")
    return "\n".join(lines)


def fit_markdown(data: dict) -> str:
    """fit_report.md: the parameters and the replay of each log."""
    lines = ["# Identified plant", "", "| parameter | value | ci95 | unit |", "|---|---|---|---|"]
    for name, p in data["parameters"].items():
        lines.append(f"| {name} | {p['value']:.6g} | {_ci(p['ci95'])} | {p['unit']} |")
    for axis, params in data.get("lugre", {}).items():
        for name, p in params.items():
            lines.append(f"| {axis} {name} | {p['value']:.6g} | {_ci(p['ci95'])} | {p['unit']} |")
    if "lugre_ci95_note" in data:
        lines += ["", f"ci95 null: {data['lugre_ci95_note']}."]
    lines += ["", f"Plant: `{SCENARIO_FILE}` holds the scenario's `plant` section (`file: {PLANT_FILE}`", ""]
    lines[-2] += " and the friction, if identified); copy it into a scenario beside these files."
    lines += ["## Replay of the logged commands", "", "| log | window s | rms x um | rms y um | max x um | max y um |"]
    lines.append("|---|---|---|---|---|---|")
    for f in data["fit"]:
        r, m = f["rms_um"], f["max_um"]
        lines.append(f"| {f['path']} | {f['window_s']:g} | {r['x']:.3g} | {r['y']:.3g} | {m['x']:.3g} | {m['y']:.3g} |")
    lines += [""] + [f"![{f['path']}]({f['figure']})" for f in data["fit"]]
    return "\n".join(lines) + "\n"
