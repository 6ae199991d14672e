"""Figures of one run (``plots/*.png``, svg or pdf, in its directory) and of several runs overlaid (``compare``).

Drawn with matplotlib (Agg) from a run's ``trace.parquet`` and ``summary.json``,
read a row group at a time so that a long run is drawn in bounded memory:
each series is cut into at most :data:`PLOT_BINS` bins of consecutive rows
and each bin keeps its row of largest abs(value) (:func:`envelope`: spikes
survive), the estimates the first row of each bin. The trace's rows are every
``outputs.trace_stride``-th sample; the times come from its ``t_s`` column.

Figures (units on every axis; the window of each figure in its title):

- ``eps_c.png``: the true contour error eps_c(t), um, the metric window shaded;
- ``axial_errors.png``: e_x, e_y = q - q_d (t), um;
- ``commands.png``: u_x, u_y (t), V, scaled to the data; the motor's limits (``saturation.limit_v`` of
  summary.json) drawn when in range, else named in the panel's text;
- ``estimates.png``: theta^ (t) of each parameter against its true value (dashed), volt units; only when
  the controller logs ``theta_hat``; a panel whose estimate summary.json does not trust is greyed, hatched,
  and titled "not trusted: why";
- ``contour.png``: the desired path, mm, and around it the contour error magnified: the points
  q_d + k eps_c n (n the unit normal to the left of the direction of travel, the side where eps_c > 0),
  k in the legend;
- ``part.png`` (a part program's run, given its plan): the programmed part with the part error along it,
  magnified and colour-coded, its worst blocks and corners marked (:mod:`gantry_twin.outputs.part_plot`).
"""

from __future__ import annotations

import json
import math
import textwrap
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gantry_twin.outputs.part_plot import PartBins, PartSeries, fig_part
from gantry_twin.outputs.summary import RunSummary
from gantry_twin.plant.model import AXES, THETA_NAMES, short_label

#: Each series is cut into at most this many bins (the points drawn per line).
PLOT_BINS = 3000
#: The unit of each theta (the paper's volt units): M in V s^2/m, B in V s/m, Af and dN in V.
THETA_UNITS = {"M": "V s²/m", "B": "V s/m", "Af": "V", "dN": "V"}
#: The contour figure magnifies eps_c so that its largest value is about this share of the path's size.
MAGNIFIED_SHARE = 0.12
#: A figure's title names the run in at most this many characters.
TITLE_CHARS = 110
#: The commands' panels: the data in the lower LABEL_ROOM of the height, the limits' label above it.
LABEL_ROOM = 0.86
#: Height added to a figure for a legend below its x label, inches.
LEGEND_BELOW_IN = 0.3
#: An untrusted estimate's reason above its panel: lines of at most this many characters, two lines at most.
DOUBT_CHARS = 90
#: Figure resolution, dots per inch (png; svg and pdf are vector).
DPI = 150
#: The file formats a figure can be written in.
PLOT_FORMATS = ("png", "svg", "pdf")

_TRACE_COLUMNS = ("t_s", "x_d_m", "y_d_m", "e_x_m", "e_y_m", "eps_c_m", "u_x_v", "u_y_v")


def envelope(t: np.ndarray, x: np.ndarray, bin_size: int) -> tuple[np.ndarray, np.ndarray]:
    """Per bin of ``bin_size`` samples (the last one shorter), the time and value of the largest abs(x)."""
    idx = _peaks(x, bin_size)
    return t[idx], x[idx]


def _peaks(x: np.ndarray, bin_size: int) -> np.ndarray:
    """The index of the largest abs(x) of each bin of ``bin_size`` samples (the last bin may be shorter)."""
    n = (x.size // bin_size) * bin_size
    idx = np.argmax(np.abs(x[:n].reshape(-1, bin_size)), axis=1) + np.arange(n // bin_size) * bin_size
    if n < x.size:
        idx = np.append(idx, n + int(np.argmax(np.abs(x[n:]))))
    return idx


@dataclass
class RunSeries:
    """One run's series, binned for drawing: times s, errors um, commands V, positions m, estimates volt units."""

    label: str
    summary: RunSummary
    t_eps_s: np.ndarray
    eps_c_um: np.ndarray
    contour_m: np.ndarray  # (n, 4): x_d, y_d and the path's unit left normal at the eps_c peaks
    axial: list[tuple[np.ndarray, np.ndarray]]  # per axis: t s, e um
    command: list[tuple[np.ndarray, np.ndarray]]  # per axis: t s, u V
    t_theta_s: np.ndarray | None = None
    theta_hat: np.ndarray | None = None  # (n, 8)
    true_theta: np.ndarray | None = None  # (n, 8)
    notes: list[str] = field(default_factory=list)
    part: PartSeries | None = None  # a part program's run: its part error (gantry_twin.outputs.part_plot)


class _Bins:
    """Gathers the binned series of a trace read a block of rows at a time."""

    def __init__(self, bin_size: int, theta: bool, plan: Any = None) -> None:
        self.bin_size, self.theta = bin_size, theta
        self.parts: dict[str, list[np.ndarray]] = {}
        self.part = PartBins(plan, bin_size) if plan is not None else None

    def _add(self, key: str, values: np.ndarray) -> None:
        self.parts.setdefault(key, []).append(values)

    def block(self, c: dict[str, np.ndarray]) -> None:
        """Rows of whole bins (the last block of the trace may end with a shorter bin)."""
        t, b = c["t_s"], self.bin_size
        peak = _peaks(c["eps_c_m"], b)
        normal = _left_normal(c["x_d_m"], c["y_d_m"])
        self._add("t_eps", t[peak])
        self._add("eps", c["eps_c_m"][peak] * 1e6)
        self._add("contour", np.column_stack([c["x_d_m"][peak], c["y_d_m"][peak], normal[peak]]))
        for axis in AXES:
            for key, scale in ((f"e_{axis}_m", 1e6), (f"u_{axis}_v", 1.0)):
                i = _peaks(c[key], b)
                self._add(f"t_{key}", t[i])
                self._add(key, c[key][i] * scale)
        if self.part is not None:
            self.part.block(t, np.column_stack([c["x_m"], c["y_m"]]))
        if self.theta:
            first = np.arange(0, t.size, b)
            self._add("t_theta", t[first])
            self._add("theta", np.column_stack([c[f"theta_hat_{n}"][first] for n in THETA_NAMES]))
            if "true_theta_M1" in c:
                self._add("true", np.column_stack([c[f"true_theta_{n}"][first] for n in THETA_NAMES]))

    def get(self, key: str) -> np.ndarray:
        return np.concatenate(self.parts[key])


def _left_normal(x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
    """(n, 2) unit left normal of the path through the points (NaN where it does not move)."""
    if x_m.size < 2:
        return np.full((x_m.size, 2), np.nan)
    tx, ty = np.gradient(x_m), np.gradient(y_m)
    norm = np.hypot(tx, ty)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.column_stack([-ty / norm, tx / norm])


def read_series(run_dir: Path, summary: RunSummary, label: str, plan: Any = None) -> RunSeries | None:
    """A run's series binned for drawing, read from ``run_dir/trace.parquet`` (None if it has none); ``plan``:
    the run's part program (a :class:`~gantry_twin.gcode.sampling.Plan`), whose part error is drawn too."""
    import pyarrow.parquet as pq

    path = Path(run_dir) / "trace.parquet"
    if not path.is_file():
        return None
    pf = pq.ParquetFile(path)
    names = set(pf.schema_arrow.names)
    theta = all(f"theta_hat_{n}" in names for n in THETA_NAMES)
    columns = list(_TRACE_COLUMNS) + (["x_m", "y_m"] if plan is not None else [])
    if theta:
        columns += [f"theta_hat_{n}" for n in THETA_NAMES]
        columns += [f"true_theta_{n}" for n in THETA_NAMES if f"true_theta_{n}" in names]
    rows = pf.metadata.num_rows
    if rows == 0:
        return None
    bins = _Bins(max(1, math.ceil(rows / PLOT_BINS)), theta, plan)
    carry: dict[str, np.ndarray] | None = None
    for group in range(pf.metadata.num_row_groups):  # one at a time: memory bounded by a row group
        table = pf.read_row_group(group, columns=columns, use_threads=False)
        block = {name: table.column(name).to_numpy() for name in columns}
        del table
        if carry is not None:
            block = {name: np.concatenate([carry[name], block[name]]) for name in columns}
        whole = (block["t_s"].size // bins.bin_size) * bins.bin_size
        if whole:
            bins.block({name: v[:whole] for name, v in block.items()})
        carry = {name: v[whole:] for name, v in block.items()}
    if carry is not None and carry["t_s"].size:
        bins.block(carry)
    series = RunSeries(
        label=label,
        summary=summary,
        t_eps_s=bins.get("t_eps"),
        eps_c_um=bins.get("eps"),
        contour_m=bins.get("contour"),
        axial=[(bins.get(f"t_e_{a}_m"), bins.get(f"e_{a}_m")) for a in AXES],
        command=[(bins.get(f"t_u_{a}_v"), bins.get(f"u_{a}_v")) for a in AXES],
        part=bins.part.series() if bins.part is not None else None,
    )
    if theta:
        series.t_theta_s, series.theta_hat = bins.get("t_theta"), bins.get("theta")
        if "true" in bins.parts:
            series.true_theta = bins.get("true")
        else:  # the plant did not change: the true theta at t = 0, in the schema metadata
            meta = json.loads((pf.schema_arrow.metadata or {}).get(b"true_theta", b"{}"))
            if all(n in meta for n in THETA_NAMES):
                row = np.array([meta[n] for n in THETA_NAMES])
                series.true_theta = np.broadcast_to(row, series.theta_hat.shape)
    return series


# ---------------------------------------------------------------------------
# The figures: each takes one run's series or several (overlaid, labelled).


def _window(summary: RunSummary) -> tuple[float, float] | None:
    return summary.contour_error_um.window_s if summary.contour_error_um is not None else None


def legend_below(fig: Any, ax: Any, ncol: int = 4, **kwargs: Any) -> int:
    """``ax``'s legend in rows of ``ncol`` at the figure's bottom, under the x label: never over the data (a legend
    in a corner hid the part program's corner spikes). The figure leaves :data:`LEGEND_BELOW_IN` per row for it;
    the number of rows."""
    handles, labels = ax.get_legend_handles_labels()
    if not handles:
        return 0
    ncol = min(len(handles), ncol)
    fig.legend(handles, labels, loc="lower center", ncol=ncol, fontsize=7, frameon=False, **kwargs)
    return -(-len(handles) // ncol)


def _title(runs: Sequence[RunSeries], what: str) -> str:
    """``what``, and below it the run's label (one run; several are told apart by their legend labels)."""
    if len(runs) > 1:
        return what
    return what + "\n" + textwrap.shorten(runs[0].label, TITLE_CHARS, placeholder=" ...")


def _name(runs: Sequence[RunSeries], r: RunSeries, what: str) -> str:
    """A line's legend label: ``what`` for one run, the run's label (and ``what``) for several."""
    return what if len(runs) == 1 else f"{r.label} {what}".strip()


def fig_eps_c(plt: Any, runs: Sequence[RunSeries]) -> Any:
    """eps_c(t), µm, with the metric window (the first run's) shaded."""
    fig, ax = plt.subplots(figsize=(9, 3.6 + LEGEND_BELOW_IN))
    fig.subplots_adjust(left=0.08, right=0.98, bottom=(0.5 + LEGEND_BELOW_IN) / (3.6 + LEGEND_BELOW_IN), top=0.87)
    for r in runs:
        ax.plot(r.t_eps_s, r.eps_c_um, lw=0.7, label=_name(runs, r, "" if len(runs) > 1 else "eps_c"))
    window = _window(runs[0].summary)
    if window is not None:
        c = runs[0].summary.contour_error_um
        what = "paper's window (second period)" if c is not None and c.paper_window else "metric window"
        ax.axvspan(*window, color="0.85", zorder=0, label=f"{what} [{window[0]:.2f}, {window[1]:.2f}] s")
    _shade_rapids(ax, runs[0].part)  # eps_c there is not the part's (the part error leaves them out)
    ax.axhline(0.0, color="0.4", lw=0.5)
    ax.set(xlabel="time t (s)", ylabel="contour error eps_c (µm)")
    ax.set_title(_title(runs, "true contour error eps_c (largest |eps_c| of each bin)"), fontsize=9)
    legend_below(fig, ax)
    return fig


def _rapid_spans(part: PartSeries | None) -> list[tuple[float, float]]:
    """(start, end) s of a part program's rapid (G0) moves; none for a contour's run."""
    return [] if part is None else part.plan.rapid_spans()


def _shade_rapids(ax: Any, part: PartSeries | None) -> None:
    """Hatch a part program's rapid moves on a time axis (labelled once): not part of the part, where the errors and
    commands of positioning at the rapid feed are not the part's."""
    spans = _rapid_spans(part)
    for i, (a, b) in enumerate(spans):
        label = f"rapid (G0) moves ({len(spans)})" if i == 0 else None
        ax.axvspan(a, b, facecolor="none", edgecolor="tab:red", hatch="//", lw=0, alpha=0.4, label=label)


def _per_axis(plt: Any, runs: Sequence[RunSeries], series: str, ylabel: str, title: str, decorate: Any = None) -> Any:
    """One panel per axis of ``RunSeries.<series>[axis]`` (t, values) for every run; ``decorate(ax, axis)`` adds
    what a panel needs besides (limits); ``ylabel`` is formatted with ``axis``. A part program's rapid moves are
    hatched (the first run's)."""
    rapids = bool(_rapid_spans(runs[0].part))
    below = LEGEND_BELOW_IN if len(runs) > 1 or rapids else 0.0  # a legend of the runs' labels, or the rapids, below
    fig, axes = plt.subplots(2, 1, figsize=(9, 5 + below), sharex=True)
    fig.subplots_adjust(left=0.09, right=0.98, bottom=(0.5 + below) / (5 + below), top=0.89, hspace=0.08)
    for i, (ax, axis) in enumerate(zip(axes, AXES, strict=True)):
        for r in runs:
            t, values = getattr(r, series)[i]
            ax.plot(t, values, lw=0.7, label=_name(runs, r, ""))
        if decorate is not None:
            decorate(ax, axis)
        _shade_rapids(ax, runs[0].part)
        ax.set_ylabel(ylabel.format(axis=axis))
    if len(runs) > 1 or rapids:
        legend_below(fig, axes[0])
    axes[-1].set_xlabel("time t (s)")
    axes[0].set_title(_title(runs, title), fontsize=9)
    return fig


def fig_axial(plt: Any, runs: Sequence[RunSeries]) -> Any:
    """e_x(t), e_y(t), um."""

    def zero_line(ax: Any, axis: str) -> None:
        ax.axhline(0.0, color="0.4", lw=0.5)

    return _per_axis(
        plt,
        runs,
        "axial",
        "e_{axis} = {axis} - {axis}_d (µm)",
        "axial tracking errors (largest |e| of each bin)",
        zero_line,
    )


def fig_commands(plt: Any, runs: Sequence[RunSeries]) -> Any:
    """u_x(t), u_y(t), V, with the motor's limits."""

    def limits(ax: Any, axis: str) -> None:
        saturation = runs[0].summary.saturation or {}
        limit = saturation[axis].limit_v if axis in saturation else None
        if limit:
            low, high = ax.get_ylim()  # the data's range: a limit far outside it is named, not drawn
            inside = [v for v in limit if low <= v <= high]
            for v in inside:
                ax.axhline(v, color="tab:red", lw=0.8, ls="--")
            label = f"limits {limit[0]:+g} / {limit[1]:+g} V" + ("" if len(inside) == 2 else " (off the scale)")
            box = {"facecolor": "white", "edgecolor": "0.8", "alpha": 0.9, "pad": 2}
            ax.text(0.005, 0.96, label, transform=ax.transAxes, va="top", fontsize=7, color="tab:red", bbox=box)
            if len(inside) < 2:  # headroom for the label: the data below it (it hid u_y's start on a circle)
                high = max(high, low + (high - low) / LABEL_ROOM)
            ax.set_ylim(low, high)

    return _per_axis(
        plt, runs, "command", "command u_{axis} (V)", "commands as applied (largest |u| of each bin)", limits
    )


def fig_estimates(plt: Any, runs: Sequence[RunSeries]) -> Any | None:
    """theta^(t) per parameter with the true value dashed; None when no run has estimates."""
    runs = [r for r in runs if r.theta_hat is not None]
    if not runs:
        return None
    fig, axes = plt.subplots(4, 2, figsize=(10, 9.5), sharex=True)
    fig.subplots_adjust(left=0.09, right=0.98, bottom=0.055, top=0.88, wspace=0.28, hspace=0.2)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for j, (ax, name) in enumerate(zip(axes.T.ravel(), THETA_NAMES, strict=True)):
        low, high = [], []
        for k, r in enumerate(runs):
            colour = colours[k % len(colours)]
            ax.plot(r.t_theta_s, r.theta_hat[:, j], lw=0.9, color=colour, label=_name(runs, r, "estimate"))
            low.append(np.nanmin(r.theta_hat[:, j]))
            high.append(np.nanmax(r.theta_hat[:, j]))
            if r.true_theta is not None:
                ax.plot(r.t_theta_s, r.true_theta[:, j], lw=0.9, ls="--", color=colour, label=_name(runs, r, "true"))
                low.append(np.nanmin(r.true_theta[:, j]))
                high.append(np.nanmax(r.true_theta[:, j]))
        lo, hi = float(np.nanmin(low)), float(np.nanmax(high))
        margin = 0.1 * max(hi - lo, 0.05 * max(abs(lo), abs(hi)), 1e-3)
        ax.set_ylim(lo - margin, hi + margin)  # the true value inside, with a margin
        unit = THETA_UNITS[name.rstrip("12")]
        ax.set_ylabel(f"{name} ({unit})")
        doubt = _distrust(runs, name)
        if doubt:
            ax.set_facecolor("0.93")
            ax.patch.set_hatch("///")
            ax.patch.set_edgecolor("0.8")
            lines = textwrap.wrap(doubt, DOUBT_CHARS, max_lines=2, placeholder=" ...")
            ax.set_title("\n".join(lines), fontsize=6.5, color="0.35", pad=2)
        window = runs[0].summary.estimates_window_s
        if window is not None:  # where the summary's mean estimate is taken
            label = f"estimates window [{window[0]:.2f}, {window[1]:.2f}] s" if j == 0 else None
            ax.axvspan(*window, color="tab:green", alpha=0.08, zorder=0, label=label)
    for ax in axes[-1]:
        ax.set_xlabel("time t (s)")
    # One legend for every panel, between the title and the panels (in a panel, "best" still covered the data).
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.935), ncol=4, fontsize=7, frameon=False)
    fig.suptitle(_title(runs, "parameter estimates theta^ (solid) and true values (dashed), volt units"), fontsize=9)
    return fig


def _distrust(runs: Sequence[RunSeries], name: str) -> str:
    """``not trusted: why`` when a run's summary.json does not trust its estimate of ``name``; empty otherwise."""
    for r in runs:
        e = (r.summary.estimates or {}).get(name)
        if e is not None and e.distrust:
            return e.distrust if len(runs) == 1 else f"{r.label}: {e.distrust}"
    return ""


def magnification(runs: Sequence[RunSeries]) -> float:
    """A round factor (1, 2 or 5 x 10^n) that makes the largest eps_c about MAGNIFIED_SHARE of the path's size."""
    size = max(float(np.ptp(r.contour_m[:, :2], axis=0).max()) for r in runs)
    peak = max(float(np.nanmax(np.abs(r.eps_c_um))) * 1e-6 for r in runs)
    if peak <= 0.0 or size <= 0.0:
        return 1.0
    raw = MAGNIFIED_SHARE * size / peak
    decade = 10.0 ** math.floor(math.log10(raw))
    return max(f * decade for f in (1.0, 2.0, 5.0) if f * decade <= raw)


def fig_contour(plt: Any, runs: Sequence[RunSeries]) -> Any:
    """The desired path (mm) and q_d + k eps_c n around it, one factor k for every run."""
    k = magnification(runs)
    fig, ax = plt.subplots(figsize=(6.5, 6.5 + LEGEND_BELOW_IN))
    fig.subplots_adjust(left=0.13, right=0.97, bottom=(0.55 + LEGEND_BELOW_IN) / (6.5 + LEGEND_BELOW_IN), top=0.9)
    path = runs[0].contour_m  # in the order of time: any path, closed or not
    ax.plot(path[:, 0] * 1e3, path[:, 1] * 1e3, color="0.5", lw=0.8, label="desired path q_d")
    for r in runs:
        c = r.contour_m
        points = c[:, :2] + k * (r.eps_c_um * 1e-6)[:, None] * c[:, 2:4]
        ax.plot(points[:, 0] * 1e3, points[:, 1] * 1e3, ".", ms=1.2, label=_name(runs, r, f"q_d + {k:g} eps_c n"))
    ax.set_aspect("equal", adjustable="datalim")
    ax.set(xlabel="x (mm)", ylabel="y (mm)")
    ax.set_title(
        _title(runs, f"contour error magnified {k:g}x around the path (eps_c > 0: left of the travel)"), fontsize=9
    )
    legend_below(fig, ax, markerscale=6)  # in the corner it hid the path of the second run of a compare
    return fig


#: The figure files and what draws them.
FIGURES: dict[str, Callable[[Any, Sequence[RunSeries]], Any]] = {
    "eps_c.png": fig_eps_c,
    "axial_errors.png": fig_axial,
    "commands.png": fig_commands,
    "estimates.png": fig_estimates,
    "contour.png": fig_contour,
}
#: The figures of a part program's run besides (drawn when a run has a ``part``).
PROGRAM_FIGURES: dict[str, Callable[[Any, Sequence[RunSeries]], Any]] = {
    "part.png": lambda plt, runs: fig_part(plt, runs, runs[0].label if len(runs) == 1 else ""),
}


def pyplot() -> Any:
    """matplotlib's pyplot on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def draw(runs: Sequence[RunSeries], directory: Path, fmt: str = "png", dpi: float = DPI) -> list[str]:
    """Write each figure of ``runs`` (overlaid) into ``directory`` as ``fmt`` (:data:`PLOT_FORMATS`) at ``dpi``;
    the file names written."""
    if fmt not in PLOT_FORMATS:
        raise ValueError(f"plot format {fmt!r}: expected one of {', '.join(PLOT_FORMATS)}")
    plt = pyplot()
    written = []
    for png, draw_one in {**FIGURES, **PROGRAM_FIGURES}.items():
        fig = draw_one(plt, runs)
        if fig is None:
            continue
        name = str(Path(png).with_suffix(f".{fmt}"))
        fig.savefig(directory / name, dpi=dpi)
        plt.close(fig)
        written.append(name)
    return written


def write_plots(
    run_dir: Path, plots_dir: Path, summary: RunSummary, fmt: str = "png", dpi: float = DPI, plan: Any = None
) -> list[str]:
    """The figures of the run in ``run_dir`` (its trace.parquet, its summary ``summary``; ``plan`` its part
    program if it ran one) into ``plots_dir``, written as one directory
    (:func:`gantry_twin.outputs.files.atomic_write_dir`); the file names."""
    from gantry_twin.outputs.files import atomic_write_dir

    series = read_series(run_dir, summary, run_label(summary), plan)
    if series is None:
        raise FileNotFoundError(f"{run_dir}/trace.parquet: no trace to draw")
    names: list[str] = []
    atomic_write_dir(plots_dir, lambda tmp: names.extend(draw([series], tmp, fmt, dpi)))
    return names


def run_label(summary: RunSummary) -> str:
    """``<scenario> with <controller> on the <plant>`` and the command line's overrides: how the printed header
    names a run."""
    label = f"{summary.scenario or summary.log or '?'} with {summary.controller}"
    if summary.plant is not None:
        label += f" on the {short_label(summary.plant)}"
    overrides = summary.overrides or []
    if overrides:
        label += " (" + " ".join(f"--set {o}" for o in overrides) + ")"
    return label
