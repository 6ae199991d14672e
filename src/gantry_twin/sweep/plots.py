"""A sweep's figures and ``summary.md``, beside ``results.parquet``.

Per swept field and plotted metric: the metric against the field's value,
every finished point as a dot (the spread over the other fields and the
seeds) and, for a grid axis, the mean per value as a line, one line per
combination of the other grid axes when there are few (e.g. one per
controller). An ``estimate_*`` metric also shows the true value, dashed.
With two or more swept fields, a heat map of the first two: the mean
metric per cell of two grid axes, else the points coloured by the metric.
"""

from __future__ import annotations

import io
import json
import math
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gantry_twin.outputs.files import atomic_write, atomic_write_text
from gantry_twin.outputs.plots import DPI, THETA_UNITS
from gantry_twin.sweep.points import STATUS_OK, Plan

SUMMARY_FILE = "summary.md"
#: At most this many lines (combinations of the other grid axes) in one plot.
MAX_SERIES = 8
#: At most this many labelled ticks on an axis of distinct values.
MAX_TICKS = 16
#: Best and worst points listed in summary.md.
LISTED = 5


#: A name's unit from its ending (the package's names carry their units), longest endings first.
UNIT_SUFFIXES = (
    ("_v_s_m", "V/(m/s)"), ("_ns_m", "N s/m"), ("_rad_s", "rad/s"), ("_m_s2", "m/s²"), ("_m_s", "m/s"),
    ("_n_m", "N/m"), ("_s_m", "s/m"), ("_um", "µm"), ("_mm", "mm"), ("_kg", "kg"), ("_rad", "rad"), ("_hz", "Hz"),
    ("_pct", "%"), ("_v", "V"), ("_n", "N"), ("_m", "m"), ("_s", "s"),
)  # fmt: skip


def unit_of(name: str) -> str:
    """The unit a field path or metric name carries (``payload.mass_kg``: kg, ``estimate_M1``: V s²/m), or ''."""
    last = name.rsplit(".", 1)[-1]
    for prefix in ("estimate_", "true_"):
        if last.startswith(prefix) and last[len(prefix) :].rstrip("12") in THETA_UNITS:
            return THETA_UNITS[last[len(prefix) :].rstrip("12")]
    if last.startswith("error_pct_"):  # an estimate's error (the results table's column), per cent
        return "%"
    for suffix, unit in UNIT_SUFFIXES:
        if last.lower().endswith(suffix):
            return unit
    return ""


def axis_label(name: str) -> str:
    """``name (unit)``: a field path or metric as the axes name it, with its unit when its name says one."""
    unit = unit_of(name)
    return f"{name} ({unit})" if unit else name


def _numeric(values: Sequence[Any]) -> bool:
    return all(isinstance(v, int | float) and not isinstance(v, bool) for v in values)


def _mean(values: Sequence[float]) -> float:
    return sum(values) / len(values)


def _save(fig: Any, path: Path) -> None:
    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI)
    plt.close(fig)
    atomic_write(path, lambda fh: fh.write(buffer.getvalue()))


def _grid_fields(plan: Plan) -> list[str]:
    return [a.field for a in plan.spec.axes]


def _series(plan: Plan, rows: list[dict[str, Any]], field: str) -> dict[str, list[dict[str, Any]]]:
    """Rows grouped by the values of the other grid axes (one group if that makes too many)."""
    others = [f for f in _grid_fields(plan) if f != field]
    groups: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for row in rows:
        groups[", ".join(f"{f}={row[f]}" for f in others)].append(row)
    return groups if len(groups) <= MAX_SERIES else {"": rows}


def _flat(value: Any, prefix: str = "") -> dict[str, Any]:
    """A JSON object as {dotted key: leaf}; anything else as {prefix: value}."""
    if isinstance(value, dict):
        return {k: v for key, item in value.items() for k, v in _flat(item, f"{prefix}{key}.").items()}
    return {prefix.rstrip("."): value}


def tick_labels(values: Sequence[Any]) -> list[str]:
    """Short axis labels: numbers to 4 digits; values that are JSON objects (a swept ``contour``) by the leaves
    that differ between them (``type=circle radius_m=0.02 rate_rad_s=1``), not the whole object."""
    if _numeric(values):
        return [f"{v:.4g}" for v in values]
    try:
        flats = [_flat(json.loads(v)) if isinstance(v, str) and v.startswith("{") else None for v in values]
    except ValueError:
        flats = [None]
    if not flats or any(f is None for f in flats):
        return [str(v) for v in values]
    keys = list(dict.fromkeys(k for f in flats for k in f))
    # a leaf some objects lack (an ellipse's semi-axes beside circles) or whose value differs between them
    varying = [k for k in keys if len({json.dumps(f[k]) if k in f else "" for f in flats}) > 1]
    return [" ".join(f"{k.rsplit('.', 1)[-1]}={f[k]}" for k in varying if k in f) for f in flats]


def _set_ticks(axis: Any, labels: list[str], rotation: float = 0) -> None:
    """Every label when there are few, else every k-th (at most MAX_TICKS), so that they stay legible."""
    step = max(1, math.ceil(len(labels) / MAX_TICKS))
    longest = max((len(label) for label in labels), default=0)
    small = longest > 20
    axis.set_ticks(range(0, len(labels), step), labels[::step], rotation=rotation, fontsize=7 if small else None)
    if small:  # room for the labels beside a plot of the usual size (about 0.055 in a character at 7 pt)
        fig = axis.axes.figure
        width, height = fig.get_size_inches()
        extent = longest * 0.055 * (math.sin(math.radians(rotation)) if axis.axis_name == "x" else 1.0)
        fig.set_size_inches(
            width + (extent if axis.axis_name == "y" else 0), height + (extent if axis.axis_name == "x" else 0)
        )


def _positions(values: Sequence[Any]) -> tuple[list[float], list[Any] | None]:
    """x positions of values: the numbers themselves, else the index of each distinct value (and the labels)."""
    if _numeric(values):
        return [float(v) for v in values], None
    labels = list(dict.fromkeys(values))
    return [float(labels.index(v)) for v in values], labels


def trust_column(metric: str) -> str | None:
    """The results table's ``trustworthy_<name>`` column that judges an estimate's metric (``estimate_<name>``,
    ``error_pct_<name>``); None for any other metric."""
    for prefix in ("estimate_", "error_pct_"):
        if metric.startswith(prefix):
            return "trustworthy_" + metric.removeprefix(prefix)
    return None


def metric_plot(plan: Plan, rows: list[dict[str, Any]], field: str, metric: str, out: Path) -> str | None:
    """``<metric>_vs_<field>.png``; None when no finished point has the metric. An estimate's points that the run's
    confidence tests did not trust (``trustworthy_<name>`` false) are drawn hollow, and counted in the title."""
    import matplotlib.pyplot as plt

    rows = [r for r in rows if r.get(metric) is not None]
    if not rows:
        return None
    _, labels = _positions([r[field] for r in rows])
    fig, ax = plt.subplots(figsize=(7, 4.2), layout="constrained")
    is_grid = field in _grid_fields(plan)
    true_column = "true_" + metric.removeprefix("estimate_") if metric.startswith("estimate_") else None
    trusted = trust_column(metric)
    untrusted = 0
    for name, group in _series(plan, rows, field).items():
        xs, _ = (
            _positions([r[field] for r in group]) if labels is None else ([labels.index(r[field]) for r in group], None)
        )
        doubted = [trusted is not None and r.get(trusted) is False for r in group]
        untrusted += sum(doubted)
        solid = [(x, r[metric]) for x, r, d in zip(xs, group, doubted, strict=True) if not d]
        hollow = [(x, r[metric]) for x, r, d in zip(xs, group, doubted, strict=True) if d]
        dots = ax.plot(*_columns(solid), "o", ms=4, alpha=0.6, label=name or None)[0]
        if hollow:
            ax.plot(*_columns(hollow), "o", ms=5, mfc="none", color=dots.get_color(), alpha=0.8)
        by_x: dict[float, list[dict[str, Any]]] = defaultdict(list)
        for x, r in zip(xs, group, strict=True):
            by_x[x].append(r)
        order = sorted(by_x)
        categorical = labels is not None  # categories: a mark per category, no line from one to the next
        if is_grid and (len(order) > 1 or categorical):
            means = [_mean([r[metric] for r in by_x[x]]) for x in order]
            style = {"ls": "none", "marker": "_", "ms": 16, "mew": 1.5} if categorical else {"ls": "-"}
            ax.plot(order, means, color=dots.get_color(), **style)
        if true_column and all(r.get(true_column) is not None for r in group):
            true = [_mean([r[true_column] for r in by_x[x]]) for x in order]
            style = {"ls": "none", "marker": "_", "ms": 22, "mew": 0.9} if categorical else {"ls": "--", "lw": 0.9}
            ax.plot(order, true, color=dots.get_color(), **style)
    if labels is not None:
        _set_ticks(ax.xaxis, tick_labels(labels), rotation=45 if len(labels) > 4 else 0)
    ax.set_xlabel(axis_label(field))
    true_mark = "a wide bar" if labels is not None else "dashed"
    ax.set_ylabel(axis_label(metric) + (f"; true value: {true_mark}" if true_column else ""))
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[1]:
        ax.legend(fontsize=7)
    doubt = f", {untrusted} not trusted: hollow" if untrusted else ""
    ax.set_title(f"{metric} against {field} ({len(rows)} points{doubt})")
    name = f"{metric}_vs_{field}.png"
    _save(fig, out / name)
    return name


def _columns(points: list[tuple[float, float]]) -> tuple[list[float], list[float]]:
    """(xs, ys) of (x, y) pairs; two empty lists for none."""
    return [x for x, _ in points], [y for _, y in points]


def heat_map(plan: Plan, rows: list[dict[str, Any]], fx: str, fy: str, metric: str, out: Path) -> str | None:
    """``<metric>_<fx>_x_<fy>.png``: mean metric per cell of two grid axes, else the points coloured by it."""
    import matplotlib.pyplot as plt

    rows = [r for r in rows if r.get(metric) is not None]
    if not rows:
        return None
    fig, ax = plt.subplots(figsize=(7, 5), layout="constrained")
    grid = _grid_fields(plan)
    if fx in grid and fy in grid:
        xs = list(dict.fromkeys(r[fx] for r in sorted(rows, key=lambda r: r["point"])))
        ys = list(dict.fromkeys(r[fy] for r in sorted(rows, key=lambda r: r["point"])))
        cells: dict[tuple[int, int], list[float]] = defaultdict(list)
        for r in rows:
            cells[(ys.index(r[fy]), xs.index(r[fx]))].append(r[metric])
        image = [
            [_mean(cells[(j, i)]) if (j, i) in cells else math.nan for i in range(len(xs))] for j in range(len(ys))
        ]
        shown = ax.imshow(image, origin="lower", aspect="auto", cmap="viridis")
        _set_ticks(ax.xaxis, tick_labels(xs), rotation=45)
        _set_ticks(ax.yaxis, tick_labels(ys))
    else:
        px, xlabels = _positions([r[fx] for r in rows])
        py, ylabels = _positions([r[fy] for r in rows])
        shown = ax.scatter(px, py, c=[r[metric] for r in rows], cmap="viridis", s=25)
        if xlabels is not None:
            _set_ticks(ax.xaxis, tick_labels(xlabels), rotation=45 if len(xlabels) > 4 else 0)
        if ylabels is not None:
            _set_ticks(ax.yaxis, tick_labels(ylabels))
    fig.colorbar(shown, ax=ax, label=axis_label(metric) + (", mean per cell" if fx in grid and fy in grid else ""))
    ax.set_xlabel(axis_label(fx))
    ax.set_ylabel(axis_label(fy))
    ax.set_title(f"{metric} over {fx} and {fy}")
    name = f"{metric}_{fx}_x_{fy}.png"
    _save(fig, out / name)
    return name


def write_figures(plan: Plan, rows: list[dict[str, Any]], out: Path) -> list[str]:
    """Every figure of the sweep (PNG files in ``out``); returns their names."""
    import matplotlib

    matplotlib.use("Agg")
    ok = [r for r in rows if r.get("status") == STATUS_OK]
    made = []
    for metric in plan.spec.plot_metrics():
        for field in plan.fields:
            made.append(metric_plot(plan, ok, field, metric, out))
        if len(plan.fields) >= 2:
            made.append(heat_map(plan, ok, plan.fields[0], plan.fields[1], metric, out))
    return [m for m in made if m is not None]


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return "-" if value is None else str(value)


def write_summary(plan: Plan, rows: list[dict[str, Any]], figures: list[str], out: Path, note: str = "") -> Path:
    """``summary.md``: what ran, how many finished, the best and worst points, failures, the figures."""
    ok = [r for r in rows if r.get("status") == STATUS_OK]
    failed = [r for r in rows if r.get("status") not in (None, STATUS_OK)]
    spec = plan.spec
    lines = [f"# Sweep {Path(plan.source).name}", ""]
    if spec.description:
        lines += [spec.description, ""]
    lines += [
        f"Scenario `{plan.scenario_source}`; {len(plan.points)} points over "
        + (", ".join(f"`{f}`" for f in plan.fields) or "no field")
        + f"; gantry-twin {plan.version}.",
        "",
        f"Finished: {len(ok)} ok, {len(failed)} failed, {len(plan.points) - len(ok) - len(failed)} not run."
        + (f" {note}" if note else ""),
        "",
    ]
    columns = ["point", *plan.fields, *spec.plot_metrics()]
    for metric in spec.plot_metrics():
        ranked = sorted((r for r in ok if r.get(metric) is not None), key=lambda r: r[metric])
        if not ranked:
            continue
        for title, chosen in (("lowest", ranked[:LISTED]), ("highest", ranked[::-1][:LISTED])):
            lines += [f"## {title.capitalize()} {metric}", "", "| " + " | ".join(columns) + " |"]
            lines.append("|---" * len(columns) + "|")
            lines += ["| " + " | ".join(_fmt(r.get(c)) for c in columns) + " |" for r in chosen]
            lines.append("")
    if failed:
        lines += ["## Failed points", "", "| point | error |", "|---|---|"]
        lines += [f"| {r['point']} | {r.get('error') or '-'} |" for r in failed[:20]]
        lines.append("")
    if figures:
        lines += ["## Figures", ""] + [f"![{name}]({name})\n" for name in figures]
    path = out / SUMMARY_FILE
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path
