"""What a tune leaves in DIR (docs/tune.md): trials.parquet, the best design (the feasible trial of the smallest
worst soft f; no trial that breaks a hard goal is ever the best), tuned.yaml, summary.md, the figures, and the
baseline's and the tuned design's runs on the nominal scenario, for ``gantry-twin compare``."""

from __future__ import annotations

import io
import json
import math
import time
from pathlib import Path
from typing import Any

import pyarrow as pa

from gantry_twin.outputs.files import atomic_write, atomic_write_text, write_parquet
from gantry_twin.scenario import apply_overrides, dump_yaml
from gantry_twin.sweep.points import override
from gantry_twin.tune.goals import Check
from gantry_twin.tune.plan import TunePlan

TRIALS_FILE = "trials.parquet"
SUMMARY_FILE = "summary.md"
TUNED_FILE = "tuned.yaml"
BASELINE_RUN, TUNED_RUN = "baseline", "tuned"
ATTR_F, ATTR_METRICS, ATTR_CONSTRAINTS, ATTR_ERROR = "f", "metrics", "constraints", "error"


def feasible(trial: Any) -> bool:
    """A complete trial that meets every hard goal (f <= 1)."""
    from optuna.trial import TrialState

    return trial.state == TrialState.COMPLETE and all(c <= 0.0 for c in trial.user_attrs.get(ATTR_CONSTRAINTS, [1]))


def soft_worst(plan: TunePlan, trial: Any) -> float:
    """The largest soft f of a trial (systune's objective for several soft goals)."""
    f = trial.user_attrs.get(ATTR_F) or []
    soft = [v for v, g in zip(f, plan.spec.goals, strict=False) if g.kind == "soft" and v is not None]
    return max(soft) if soft else math.inf


def best_trial(plan: TunePlan, study: Any) -> Any | None:
    """The feasible trial of the smallest worst soft f (the earliest of equals); None when none is feasible."""
    found = [t for t in study.get_trials(deepcopy=False) if feasible(t)]
    return min(found, key=lambda t: (soft_worst(plan, t), t.number)) if found else None


def _rows(plan: TunePlan, study: Any) -> list[dict[str, Any]]:
    rows = []
    for t in study.get_trials(deepcopy=False):
        row: dict[str, Any] = {"trial": t.number, "state": t.state.name}
        for d in plan.spec.design:
            row[d.label] = t.params.get(d.label)
        f = t.user_attrs.get(ATTR_F) or [None] * len(plan.spec.goals)
        for g, v in zip(plan.spec.goals, f, strict=False):
            row[f"f_{g.label}"] = v
        row["feasible"] = feasible(t)
        row["soft_worst"] = soft_worst(plan, t) if t.user_attrs.get(ATTR_F) else None
        metrics = t.user_attrs.get(ATTR_METRICS) or [None] * len(plan.cases)
        for case, m in zip(plan.cases, metrics, strict=False):
            for name in ("contour_rms_um", "contour_max_um", "du_rms_v"):
                row[f"{case.label}:{name}"] = None if m is None else _finite(m.get(name))
        row["error"] = t.user_attrs.get(ATTR_ERROR)
        row["wall_time_s"] = t.user_attrs.get("wall_time_s")
        rows.append(row)
    return rows


def _finite(value: Any) -> float | None:
    return float(value) if value is not None and math.isfinite(float(value)) else None


def write_trials(plan: TunePlan, study: Any, out: Path) -> Path:
    """DIR/trials.parquet: one row per trial (its design, each goal's f, feasible, each case's rms / max / du)."""
    rows = _rows(plan, study)
    columns = list(rows[0]) if rows else ["trial", "state"]
    table = pa.table({c: [r.get(c) for r in rows] for c in columns})
    meta = {"gantry_twin_tune": json.dumps({"source": plan.source, "version": plan.version})}
    path = Path(out) / TRIALS_FILE
    write_parquet(path, table.replace_schema_metadata(meta))
    return path


def tuned_scenario(plan: TunePlan, values: dict[str, float]) -> dict[str, Any]:
    """The nominal case's scenario with the design ``values``: a scenario file runnable as it is."""
    case = plan.cases[0]
    design = [override(d.field, values[d.label]) for d in plan.spec.design]
    data = apply_overrides(plan.files[str(case.path)], [*case.overrides, *design], str(case.path))
    data["description"] = f"tuned by gantry-twin tune {Path(plan.source).name}: " + ", ".join(
        f"{k} = {v:.6g}" for k, v in values.items()
    )
    data.setdefault("name", f"{case.path.stem}_tuned")
    return data


def run_pair(plan: TunePlan, values: dict[str, float], out: Path) -> list[Path]:
    """The baseline and the tuned design on the nominal case, written as ``gantry-twin run`` writes a run."""
    from gantry_twin.run import execute, write_run
    from gantry_twin.scenario import build, validate_data

    case = plan.cases[0]
    written = []
    for name, design in ((BASELINE_RUN, None), (TUNED_RUN, values)):
        resolved, _ = plan.resolve_case(case, design)
        built = build(validate_data(resolved, str(case.path)), str(case.path))
        started = time.perf_counter()
        trace = execute(built)
        write_run(Path(out) / name, built, trace, time.perf_counter() - started)
        written.append(Path(out) / name)
    return written


def _save(fig: Any, path: Path) -> None:
    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    plt.close(fig)
    atomic_write(path, lambda fh: fh.write(buffer.getvalue()))


def write_figures(plan: TunePlan, study: Any, out: Path) -> list[str]:
    """convergence.png, goals.png (each goal's f against the main design variables), pareto.png (two soft goals)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    trials = [t for t in study.get_trials(deepcopy=False) if t.user_attrs.get(ATTR_F)]
    if not trials:
        return []
    names = []
    fig, ax = plt.subplots(figsize=(7, 4.2), layout="constrained")
    numbers = [t.number for t in trials]
    worst = [soft_worst(plan, t) for t in trials]
    ok = [feasible(t) for t in trials]
    ax.scatter(
        [n for n, k in zip(numbers, ok, strict=True) if k],
        [w for w, k in zip(worst, ok, strict=True) if k],
        s=12,
        label="meets the hard goals",
    )
    ax.scatter(
        [n for n, k in zip(numbers, ok, strict=True) if not k],
        [min(w, 10.0) for w, k in zip(worst, ok, strict=True) if not k],
        s=12,
        marker="x",
        c="grey",
        label="breaks a hard goal (or pruned)",
    )
    best, line = math.inf, []
    for w, k in zip(worst, ok, strict=True):
        best = min(best, w) if k else best
        line.append(best if math.isfinite(best) else None)
    ax.step(numbers, [math.nan if v is None else v for v in line], where="post", c="C1", label="best so far")
    ax.axhline(1.0, ls=":", c="k", lw=0.8)
    ax.set(xlabel="trial", ylabel="worst soft goal f (1 = met)", title="convergence", yscale="log")
    ax.legend(fontsize=8)
    _save(fig, Path(out) / "convergence.png")
    names.append("convergence.png")

    design = plan.spec.design[:4]
    goals = plan.spec.goals
    fig, axes = plt.subplots(
        len(goals), len(design), figsize=(3.2 * len(design), 2.4 * len(goals)), layout="constrained", squeeze=False
    )
    for gi, goal in enumerate(goals):
        for di, d in enumerate(design):
            a = axes[gi][di]
            xs = [t.params.get(d.label) for t in trials]
            ys = [t.user_attrs[ATTR_F][gi] for t in trials]
            pts = [(x, min(y, 10.0)) for x, y in zip(xs, ys, strict=True) if x is not None and y is not None]
            a.scatter([p[0] for p in pts], [p[1] for p in pts], s=8)
            a.axhline(1.0, ls=":", c="k", lw=0.8)
            if d.log:
                a.set_xscale("log")
            a.set(xlabel=d.label if gi == len(goals) - 1 else "", ylabel=f"f {goal.label}" if di == 0 else "")
    _save(fig, Path(out) / "goals.png")
    names.append("goals.png")

    soft = [i for i, g in enumerate(goals) if g.kind == "soft"]
    if len(soft) == 2:
        fig, ax = plt.subplots(figsize=(5.5, 4.5), layout="constrained")
        pts = [(t.user_attrs[ATTR_F][soft[0]], t.user_attrs[ATTR_F][soft[1]]) for t in trials if feasible(t)]
        front = [p for p in pts if not any(q[0] <= p[0] and q[1] <= p[1] and q != p for q in pts)]
        ax.scatter([p[0] for p in pts], [p[1] for p in pts], s=10, c="grey", label="feasible trials")
        front.sort()
        ax.plot([p[0] for p in front], [p[1] for p in front], "o-", c="C3", label="Pareto front")
        ax.set(xlabel=f"f {goals[soft[0]].label}", ylabel=f"f {goals[soft[1]].label}", title="Pareto front")
        ax.legend(fontsize=8)
        _save(fig, Path(out) / "pareto.png")
        names.append("pareto.png")
    return names


def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return "inf" if not math.isfinite(v) else f"{v:.4g}"
    return str(v)


def write_summary(
    plan: TunePlan,
    study: Any,
    baseline: list[dict[str, float] | None],
    checks: list[Check],
    figures: list[str],
    out: Path,
    note: str = "",
) -> Path:
    """summary.md: the best design against the baseline, per goal (which bind) and per case (scenario x member)."""
    from gantry_twin.tune.goals import goal_values

    best = best_trial(plan, study)
    states: dict[str, int] = {}
    for t in study.get_trials(deepcopy=False):
        states[t.state.name] = states.get(t.state.name, 0) + 1
    lines = [f"# Tune: {Path(plan.source).name}", "", plan.spec.description.strip(), ""]
    lines.append(f"{len(study.trials)} trials: " + ", ".join(f"{n} {k.lower()}" for k, n in sorted(states.items())))
    if note:
        lines += ["", note]
    lines.append("")
    base_f = goal_values(checks, baseline)
    if best is None:
        lines += ["**No trial met every hard goal**: no tuned design (tuned.yaml not written).", ""]
    else:
        lines += [f"Best: trial {best.number} (worst soft f {soft_worst(plan, best):.4g}).", ""]
    lines += ["## Design", "", "| variable | range | baseline | tuned |", "|---|---|---|---|"]
    for d in plan.spec.design:
        tuned = best.params.get(d.label) if best is not None else None
        scale = ", log" if d.log else ""
        lines.append(
            f"| {d.label} | [{d.low:g}, {d.high:g}]{scale} | {_fmt(plan.baseline_design.get(d.label))} | "
            f"{_fmt(tuned)} |"
        )
    lines += [
        "",
        "## Goals (f <= 1 met; binding: the tuned design's hard goals with f > 0.9; limit 0: f = 1 + worst)",
        "",
        "| goal | kind | metric | limit | baseline f | tuned f | binds |",
        "|---|---|---|---|---|---|---|",
    ]
    tuned_f = best.user_attrs[ATTR_F] if best is not None else [None] * len(checks)
    for c, g, bf, tf in zip(checks, plan.spec.goals, base_f, tuned_f, strict=True):
        limit = f"{c.limit:.4g}" + (f" ({g.limit:g} x baseline)" if g.relative else "")
        # a goal of "none at all" (limit 0) is met at f = 1 exactly and binds only when broken
        binds = "yes" if c.kind == "hard" and tf is not None and tf > (1.0 if c.limit == 0 else 0.9) else ""
        lines.append(f"| {c.name} | {c.kind} | {c.metric} | {limit} | {_fmt(bf)} | {_fmt(tf)} | {binds} |")
    lines += [
        "",
        "## Per scenario and ensemble member",
        "",
        "| case | rms baseline um | rms tuned um | max baseline um | max tuned um | du rms baseline V | "
        "du rms tuned V |",
        "|---|---|---|---|---|---|---|",
    ]
    metrics = best.user_attrs[ATTR_METRICS] if best is not None else [None] * len(plan.cases)
    for case, b, m in zip(plan.cases, baseline, metrics, strict=True):
        cells = []
        for name in ("contour_rms_um", "contour_max_um", "du_rms_v"):
            cells += [_fmt(None if b is None else b[name]), _fmt(None if m is None else m[name])]
        lines.append(f"| {case.label} | " + " | ".join(cells) + " |")
    if best is not None:
        worst_b = max(b["contour_rms_um"] for b, c in zip(baseline, plan.cases, strict=True) if c.goal is None)
        worst_t = max(m["contour_rms_um"] for m, c in zip(metrics, plan.cases, strict=True) if c.goal is None)
        lines += [
            "",
            f"Worst-case rms contour error over the ensemble: baseline {worst_b:.4g} um, tuned "
            f"{worst_t:.4g} um ({100 * (1 - worst_t / worst_b):.1f} % lower).",
        ]
        lines += ["", f"Compare the nominal runs: `gantry-twin compare {out}/{BASELINE_RUN} {out}/{TUNED_RUN}`"]
    lines += ["", *[f"![{f}]({f})" for f in figures]]
    path = Path(out) / SUMMARY_FILE
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path


def write_results(
    plan: TunePlan,
    study: Any,
    baseline: list[dict[str, float] | None],
    checks: list[Check],
    out: Path,
    runs: bool = True,
    note: str = "",
) -> Any | None:
    """Every result file; the best trial (None: none feasible, and no tuned.yaml nor runs)."""
    best = best_trial(plan, study)
    if best is not None:
        atomic_write_text(Path(out) / TUNED_FILE, dump_yaml(tuned_scenario(plan, dict(best.params))))
        if runs:
            run_pair(plan, dict(best.params), out)
    write_summary(plan, study, baseline, checks, write_figures(plan, study, out), out, note)
    return best
