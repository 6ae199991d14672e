"""``gantry-twin calibrate``: plan -> cluster -> evaluations as the optimiser asks for them -> DIR/fit.json,
DIR/evaluations.jsonl (rewritten after each evaluation), DIR/plant.xml and its DIR/gantry.xml; every file
written atomically (:mod:`gantry_twin.outputs.files`)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from gantry_twin.calibration.fit import (
    Evaluation,
    Fit,
    Plan,
    calibrate,
    dumps,
    evaluation_record,
    fit_record,
    scenario_of,
)
from gantry_twin.calibration.plantfile import BODIES_FILE, plant_xml
from gantry_twin.outputs.files import atomic_write, atomic_write_text
from gantry_twin.outputs.signals import stop_signals_interrupt
from gantry_twin.plant.model import default_model_path
from gantry_twin.scenario import build

FIT_FILE = "fit.json"
EVALUATIONS_FILE = "evaluations.jsonl"
PLANT_FILE = "plant.xml"


def run_calibration(
    made: Plan,
    out: Path,
    command: str,
    workers: int | None = None,
    scheduler: str | None = None,
    evaluations: int | None = None,
    on_evaluation: Callable[[Evaluation], None] | None = None,
) -> Fit:
    """Fit ``made`` and write its files into ``out`` (made if need be, at the first evaluation)."""
    out = Path(out)  # made by the first file written: a cluster that cannot be reached leaves nothing
    lines: list[str] = []

    def record(e: Evaluation) -> None:
        lines.append(json.dumps(evaluation_record(e), allow_nan=True))
        atomic_write_text(out / EVALUATIONS_FILE, "\n".join(lines) + "\n")
        if on_evaluation is not None:
            on_evaluation(e)

    with stop_signals_interrupt():
        fit = calibrate(made, workers, scheduler, evaluations, record)
        plant = build(scenario_of(made, 0, fit.best.values), str(made.scenarios[0])).plant
        bodies = default_model_path("paper").read_bytes()
        atomic_write(out / BODIES_FILE, lambda fh: fh.write(bodies))
        atomic_write_text(out / PLANT_FILE, plant_xml(plant, command, fit.best.values))
        atomic_write_text(out / FIT_FILE, dumps({**fit_record(fit, command), "plant_file": PLANT_FILE}))
    return fit


__all__ = ["EVALUATIONS_FILE", "FIT_FILE", "PLANT_FILE", "run_calibration"]
