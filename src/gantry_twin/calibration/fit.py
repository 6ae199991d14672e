"""The calibration: plan (every target's scenario checked), evaluate a point of the free properties on the batch
runner, fit by Nelder-Mead in the unit box; what fit.json and evaluations.jsonl hold (:mod:`.driver` writes them).

A point is the free properties' values. Its runs are the targets' scenarios
with the base, the target's own ``set`` and the point's values as ``--set``
overrides, loaded as ``gantry-twin run`` loads them; the identification
constraint turns the LuGre shape (``fs_over_fc``, ``vs_m_s``,
``presliding_m``, ``zeta`` per axis) into the plant's fields (:func:`lugre_fields`).
Every evaluation is one batch of :func:`gantry_twin.sweep.points.run_point`
(the sweep's own point) on :func:`gantry_twin.sweep.engine.open_batches`.
The cost is the weighted mean squared log ratio twin / target of the given
numbers; an evaluation whose run fails costs :data:`FAILED_COST`.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gantry_twin.calibration.spec import (
    CONSTRAINED_FIELDS,
    SHAPE_FIELDS,
    CalibrationSpec,
    Target,
    friction_field,
)
from gantry_twin.plant.friction import FS_OVER_FC_DEFAULT, STRIBECK_RATIO, stribeck_fit
from gantry_twin.plant.model import Plant, moving_masses_kg
from gantry_twin.scenario import ScenarioError, apply_overrides, build, load_scenario, resolve_scenario, validate_data
from gantry_twin.sweep.points import STATUS_OK, override
from gantry_twin.theta import AXES

#: The cost of an evaluation whose run failed or whose point is not a valid plant (a penalty, not a fit).
FAILED_COST = 100.0
#: LuGre's shape where neither the spec nor the base plant gives it: Fs / Fc, vs m/s, Fc / sigma0 m, zeta.
SHAPE_DEFAULTS = {"fs_over_fc": FS_OVER_FC_DEFAULT, "vs_m_s": 0.005, "presliding_m": 3.0e-6, "zeta": 0.05}
#: How far the plant's M may be from the identification's, relative.
MASS_TOLERANCE = 0.01


@dataclass(frozen=True)
class Plan:
    """A checked calibration: the spec, where each target's scenario is, and the base plant's LuGre shape."""

    spec: CalibrationSpec
    source: str
    scenarios: tuple[Path, ...]
    shape: dict[str, dict[str, float]]  # axis -> shape name -> value, from the base plant
    masses_kg: tuple[float, float]
    gear_n_per_v: tuple[float, float]


@dataclass
class Evaluation:
    """One point: its values, each target's (rms, max) um, the cost, and a failure if any."""

    index: int
    values: dict[str, float]
    numbers: list[tuple[float, float] | None]
    cost: float
    wall_time_s: float
    error: str | None = None
    overrides: list[str] = field(default_factory=list)


def _where(source: str, where: str, exc: ScenarioError) -> ScenarioError:
    return ScenarioError(source, where, f"{exc.field}: {exc.message}" if exc.field else exc.message)


def plan(spec: CalibrationSpec, source: str) -> Plan:
    """Check everything before anything runs: each target's scenario at the start point and at every free
    property's ends (a ScenarioError names the calibration file and the field of it that is wrong)."""
    base_dir = Path(source).parent
    scenarios = []
    for i, target in enumerate(spec.targets):
        given = Path(target.scenario)
        here = given if given.is_absolute() else base_dir / given
        try:
            scenarios.append(here if here.is_file() else resolve_scenario(target.scenario))
        except FileNotFoundError as exc:
            raise ScenarioError(source, f"targets[{i}].scenario", str(exc)) from None
    for key in spec.base:
        _check_field(spec, source, key, f"base.{key}")
    for i, free in enumerate(spec.free):
        for key in free.fields():
            _check_field(spec, source, key, f"free[{i}].field")
    try:
        base = validate_data(
            apply_overrides({}, [override(k, v) for k, v in spec.base.items() if not _shape(spec, k)], ""), ""
        )
        plant = build(base, source).plant
    except ScenarioError as exc:
        raise _where(source, "base", exc) from None
    masses = moving_masses_kg(plant.model, plant.dof_index)
    gear = plant.gear_n_per_v
    if spec.identification is not None and spec.identification.M is not None:
        true_m = masses / gear
        for axis, (given, have) in enumerate(zip(spec.identification.M, true_m, strict=True)):
            if abs(given / have - 1.0) > MASS_TOLERANCE:
                raise ScenarioError(
                    source,
                    f"identification.M[{axis}]",
                    f"the base plant's M is {have:.4g} V/(m/s^2), the spec says {given:g} (a calibration does not "
                    f"move masses: within {MASS_TOLERANCE:.0%} needed; give the machine's model in base plant.file)",
                )
    made = Plan(spec, source, tuple(scenarios), _base_shape(plant), tuple(map(float, masses)), tuple(map(float, gear)))
    start = {f.label: f.start_value for f in spec.free}
    plain_base = [override(k, v) for k, v in spec.base.items() if not _shape(spec, k)]
    for i, target in enumerate(spec.targets):  # the target itself, before any free value is set on it
        try:
            load_scenario(
                scenarios[i], [*plain_base, *(override(k, v) for k, v in target.set.items())], target.controller
            )
        except ScenarioError as exc:
            raise _where(source, f"targets[{i}]", exc) from None
    for j, free in enumerate(spec.free):
        for end, value in zip(("low", "high"), free.range, strict=True):
            try:
                scenario_of(made, 0, {**start, free.label: value})
            except ScenarioError as exc:
                raise _where(source, f"free[{j}].range ({end} {value:g})", exc) from None
    for i in range(len(spec.targets)):
        try:
            build(scenario_of(made, i, start), str(scenarios[i]))
        except ScenarioError as exc:
            raise _where(source, f"targets[{i}]", exc) from None
    return made


def _shape(spec: CalibrationSpec, key: str) -> bool:
    """A LuGre shape field that the identification constraint turns into the plant's fields."""
    found = friction_field(key)
    return spec.identification is not None and found is not None and found[1] in SHAPE_FIELDS


def _check_field(spec: CalibrationSpec, source: str, key: str, where: str) -> None:
    found = friction_field(key)
    constrained = spec.identification is not None
    if found is None:
        if constrained and key.startswith("plant.friction"):
            raise ScenarioError(source, where, f"{key}: the identification constraint sets plant.friction")
        return
    name = found[1]
    if constrained and name in CONSTRAINED_FIELDS:
        raise ScenarioError(
            source,
            where,
            f"{key}: follows from the identification constraint; give {', '.join(SHAPE_FIELDS)} instead",
        )
    if constrained and name not in SHAPE_FIELDS:
        raise ScenarioError(source, where, f"{key}: unknown LuGre shape field; allowed: {', '.join(SHAPE_FIELDS)}")
    if not constrained and name in SHAPE_FIELDS and name != "vs_m_s":
        raise ScenarioError(source, where, f"{key}: a LuGre shape field needs the identification constraint")


def _base_shape(plant: Plant) -> dict[str, dict[str, float]]:
    """Each axis' LuGre shape of the base plant (its friction if LuGre, else :data:`SHAPE_DEFAULTS`)."""
    masses = moving_masses_kg(plant.model, plant.dof_index)
    out = {}
    for axis, p, mass in zip(AXES, plant.lugre_parameters(), masses, strict=True):
        if p is None:
            out[axis] = dict(SHAPE_DEFAULTS)
            continue
        critical = 2.0 * math.sqrt(p.sigma0_n_m * mass)
        out[axis] = {
            "fs_over_fc": p.fs_n / p.fc_n,
            "vs_m_s": p.vs_m_s,
            "presliding_m": p.fc_n / p.sigma0_n_m,
            "zeta": p.sigma1_ns_m / critical,
        }
    return out


def lugre_fields(
    shape: dict[str, float], af_v: float, b_v_s_m: float, mass_kg: float, gear_n_per_v: float
) -> dict[str, float]:
    """One axis' LuGre fields (SI) from its shape and the identification's Af, B (docs/rig-plant.md):

    Fc = Af kf / (1 + (r - 1) a), Fs = r Fc, sigma2 = B kf - (Fs - Fc) b with (a, b) =
    :func:`gantry_twin.plant.friction.stribeck_fit` (vs) and r = Fs / Fc, so that
    :func:`gantry_twin.plant.friction.identified_af_b` returns Af kf and B kf; sigma0 = Fc / pre-sliding distance,
    sigma1 = zeta 2 sqrt(sigma0 m).
    """
    r = min(max(shape["fs_over_fc"], STRIBECK_RATIO[0]), STRIBECK_RATIO[1])
    vs = shape["vs_m_s"]
    a, b = stribeck_fit(vs)
    fc = af_v * gear_n_per_v / (1.0 + (r - 1.0) * a)
    fs = r * fc
    sigma0 = fc / shape["presliding_m"]
    return {
        "sigma0_n_m": sigma0,
        "sigma1_ns_m": shape["zeta"] * 2.0 * math.sqrt(sigma0 * mass_kg),
        "fc_n": fc,
        "fs_n": fs,
        "vs_m_s": vs,
        "sigma2_ns_m": b_v_s_m * gear_n_per_v - (fs - fc) * b,
    }


def point_overrides(made: Plan, values: dict[str, float]) -> list[str]:
    """The ``--set`` overrides of a point (the base, then the free values, the constraint's friction last)."""
    spec = made.spec
    given = dict(spec.base)
    for free in spec.free:
        for key in free.fields():
            given[key] = float(values[free.label])
    plain = {k: v for k, v in given.items() if not _shape(spec, k)}
    out = [override(k, v) for k, v in plain.items()]
    if spec.identification is not None:
        ident = spec.identification
        out.append("plant.friction.model=lugre")
        for i, axis in enumerate(AXES):
            shape = dict(made.shape[axis])
            for key, value in given.items():
                found = friction_field(key)
                if found is not None and found[0] == axis and found[1] in SHAPE_FIELDS:
                    shape[found[1]] = float(value)
            fields = lugre_fields(shape, ident.Af[i], ident.B[i], made.masses_kg[i], made.gear_n_per_v[i])
            out += [f"plant.friction.{axis}.{k}={float(v)!r}" for k, v in fields.items()]
    return out


def scenario_of(made: Plan, target_index: int, values: dict[str, float]) -> Any:
    target: Target = made.spec.targets[target_index]
    overrides = [*point_overrides(made, values), *(override(k, v) for k, v in target.set.items())]
    return load_scenario(made.scenarios[target_index], overrides, target.controller)


def cost_of(targets: Sequence[Target], numbers: Sequence[tuple[float, float] | None]) -> float:
    """Weighted mean over the given numbers of (log(twin / target))^2; FAILED_COST if a run failed."""
    total = weights = 0.0
    for target, got in zip(targets, numbers, strict=True):
        if got is None or not all(math.isfinite(g) and g > 0 for g in got):
            return FAILED_COST
        for want, have in ((target.rms_um, got[0]), (target.max_um, got[1])):
            if want is not None:
                total += target.weight * math.log(have / want) ** 2
                weights += target.weight
    return total / weights


@dataclass
class Fit:
    """The outcome: the best evaluation, every evaluation, and the wall time, s."""

    plan: Plan
    best: Evaluation
    evaluations: list[Evaluation]
    wall_time_s: float


def calibrate(
    made: Plan,
    workers: int | None = None,
    scheduler: str | None = None,
    evaluations: int | None = None,
    on_evaluation: Callable[[Evaluation], None] | None = None,
) -> Fit:
    """Nelder-Mead (scipy) in the unit box of the free properties from their starts, every evaluation one batch
    of the targets' runs on the batch runner; deterministic for a given spec and budget."""
    from scipy.optimize import minimize

    from gantry_twin.sweep.engine import open_batches
    from gantry_twin.sweep.points import run_point

    spec = made.spec
    started = time.perf_counter()
    lows = np.array([f.range[0] for f in spec.free])
    spans = np.array([f.range[1] - f.range[0] for f in spec.free])
    x0 = (np.array([f.start_value for f in spec.free]) - lows) / spans
    step = spec.optimiser.initial_step
    simplex = [x0]
    for k in range(len(x0)):
        x = x0.copy()
        x[k] = x[k] + step if x[k] + step <= 1.0 else x[k] - step
        simplex.append(x)
    history: list[Evaluation] = []
    start_values = {f.label: f.start_value for f in spec.free}
    resolved = [scenario_of(made, i, start_values).resolved() for i in range(len(spec.targets))]

    with open_batches(resolved, made.source, workers, scheduler) as run:

        def objective(u: np.ndarray) -> float:
            unit = np.clip(u, 0.0, 1.0)
            values = {f.label: float(lo + s * x) for f, lo, s, x in zip(spec.free, lows, spans, unit, strict=True)}
            t0 = time.perf_counter()
            error = None
            numbers: list[tuple[float, float] | None] = [None] * len(spec.targets)
            overrides = point_overrides(made, values)
            try:
                points = [scenario_of(made, i, values) for i in range(len(spec.targets))]
                rows = run(run_point, [(p.resolved(), str(made.scenarios[i])) for i, p in enumerate(points)])
                for i, result in enumerate(rows):
                    row = result.row
                    if row["status"] == STATUS_OK:
                        numbers[i] = (float(row["contour_rms_um"]), float(row["contour_max_um"]))
                    else:
                        error = error or f"{spec.targets[i].name(i)}: {row['error']}"
            except ScenarioError as exc:  # a point the plant refuses (e.g. a LuGre shape out of its range)
                error = str(exc)
            cost = cost_of(spec.targets, numbers) if error is None else FAILED_COST
            cost += float(np.sum((u - unit) ** 2))  # outside the box: the clipped point's cost, a little worse
            done = Evaluation(len(history), values, numbers, cost, time.perf_counter() - t0, error, overrides)
            history.append(done)
            if on_evaluation is not None:
                on_evaluation(done)
            return cost

        budget = evaluations or spec.optimiser.evaluations
        options = {
            "maxfev": budget,
            "maxiter": budget,
            "xatol": spec.optimiser.xatol,
            "fatol": spec.optimiser.fatol,
            "initial_simplex": np.array(simplex),
        }
        minimize(objective, x0, method="Nelder-Mead", options=options)
    best = min(history, key=lambda e: (e.cost, e.index))
    return Fit(made, best, history, time.perf_counter() - started)


def residuals(made: Plan, evaluation: Evaluation) -> list[dict[str, Any]]:
    """Per target: the measured and the twin's rms and max, um, and the error twin / measured - 1, %."""
    out = []
    for i, (target, got) in enumerate(zip(made.spec.targets, evaluation.numbers, strict=True)):
        entry: dict[str, Any] = {"target": target.name(i), "scenario": target.scenario, "controller": target.controller}
        for k, what in enumerate(("rms", "max")):
            want = getattr(target, f"{what}_um")
            have = None if got is None else got[k]
            entry[f"{what}_um"] = {
                "measured": want,
                "twin": have,
                "error_pct": None if want is None or have is None else 100.0 * (have / want - 1.0),
            }
        out.append(entry)
    return out


def evaluation_record(e: Evaluation) -> dict[str, Any]:
    """One line of evaluations.jsonl."""
    return {
        "index": e.index,
        "values": e.values,
        "cost": e.cost,
        "numbers_um": [None if n is None else list(n) for n in e.numbers],
        "wall_time_s": e.wall_time_s,
        "error": e.error,
    }


def fit_record(fit: Fit, command: str) -> dict[str, Any]:
    """fit.json: the fitted values, the residuals per target, the cost, and how it was made."""
    best = fit.best
    return {
        "command": command,
        "source": fit.plan.source,
        "description": fit.plan.spec.description,
        "values": best.values,
        "cost": best.cost,
        "best_evaluation": best.index,
        "evaluations": len(fit.evaluations),
        "residuals": residuals(fit.plan, best),
        # the fitted plant as scenario overrides (``gantry-twin report --rig fit.json`` reads them), and every
        # override of the best point's runs (the base's too)
        "overrides": [o for o in best.overrides if o.startswith("plant.")],
        "run_overrides": best.overrides,
        "wall_time_s": fit.wall_time_s,
    }


def dumps(data: Any) -> str:
    return json.dumps(data, indent=2, allow_nan=True) + "\n"
