"""The figure of a part program's run: the programmed part with its error along it (``plots/part.png``).

Drawn by :mod:`gantry_twin.outputs.plots` when a run's contour is a planned
G-code program (:class:`~gantry_twin.gcode.sampling.Plan`). The part error
of a sample is its distance to the programmed lines and arcs
(:func:`gantry_twin.gcode.part_error.nearest_on_program`, the same measure as
summary.json's ``part_error``). Read a block of trace rows at a time, each
bin of rows keeps its sample of largest part error (:class:`PartBins`).

The figure (one column of XY panels per run, up to :data:`MAX_PANELS`):

- top: the programmed geometry (mm; rapids dotted), and the actual path
  drawn at p + k (q - p), p the nearest programmed point to the actual
  position q: the part error magnified k times (normal to the programmed path
  inside a move; from the end point beyond it),
  coloured by the part error (um, one colour scale for every run; k and the
  scale in the title). The worst corners of summary.json's ``part_error``
  are circled and labelled with their line and error, its worst blocks drawn
  as a wide band under the programmed path;
- bottom: the part error against time (um), the worst corners' times marked.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from gantry_twin.gcode.geometry import MoveTable
from gantry_twin.gcode.part_error import nearest_on_program
from gantry_twin.gcode.sampling import ProgramPath

#: The XY panels drawn side by side at most (runs beyond are in the time panel only).
MAX_PANELS = 3
#: The magnified part error is at most about this share of the part's size.
MAGNIFIED_SHARE = 0.1
#: Worst corners circled and worst blocks banded, per run.
MARKED = 3
#: Colour map of the part error.
COLOURS = "plasma"


@dataclass
class PartSeries:
    """One run's part error binned for drawing: times s, actual and nearest programmed points m, error m."""

    plan: ProgramPath
    t_s: np.ndarray
    q_m: np.ndarray
    nearest_m: np.ndarray
    distance_m: np.ndarray  # NaN where nothing is measured (rapids)


class PartBins:
    """Gathers, per bin of ``bin_size`` trace rows, the sample of largest part error (the bin's first sample if
    none is measured)."""

    def __init__(self, plan: ProgramPath, bin_size: int) -> None:
        self.plan, self.bin_size = plan, bin_size
        self.parts: list[tuple[np.ndarray, ...]] = []

    def block(self, t_s: np.ndarray, q_m: np.ndarray) -> None:
        """Rows of whole bins (the last block of a trace may end with a shorter bin)."""
        move = self.plan.sample(t_s).move
        distance, nearest = nearest_on_program(self.plan, move, q_m)
        b = self.bin_size
        n = (t_s.size // b) * b
        score = np.where(np.isfinite(distance), distance, -1.0)
        idx = np.argmax(score[:n].reshape(-1, b), axis=1) + np.arange(n // b) * b
        if n < t_s.size:
            idx = np.append(idx, n + int(np.argmax(score[n:])))
        self.parts.append((t_s[idx], q_m[idx], nearest[idx], distance[idx]))

    def series(self) -> PartSeries:
        t, q, p, d = (np.concatenate(a) for a in zip(*self.parts, strict=True))
        return PartSeries(self.plan, t, q, p, d)


def magnification(parts: Sequence[PartSeries]) -> float:
    """A round factor (1, 2 or 5 x 10^n) that makes the largest part error about MAGNIFIED_SHARE of the part."""
    size = max(float(np.ptp(_geometry_points(p.plan), axis=0).max()) for p in parts)
    peak = max((float(np.nanmax(p.distance_m)) for p in parts if np.isfinite(p.distance_m).any()), default=0.0)
    if peak <= 0.0 or size <= 0.0:
        return 1.0
    raw = MAGNIFIED_SHARE * size / peak
    decade = 10.0 ** math.floor(math.log10(raw))
    return max(f * decade for f in (1.0, 2.0, 5.0) if f * decade <= raw)


def _geometry_points(plan: ProgramPath) -> np.ndarray:
    return np.vstack([plan.table.polyline(k) for k in range(plan.table.count)])


def _draw_program(ax: Any, plan: ProgramPath) -> None:
    """The programmed lines and arcs, mm: feed moves solid, rapids dotted; under cutter radius compensation
    (G41 / G42) these are the tool centre's, and the part's outline as programmed is drawn thin and dashed."""
    programmed = [m for m in getattr(plan.program, "programmed_moves", ()) if not m.rapid]
    if programmed and programmed != [m for m in plan.moves if not m.rapid]:
        outline = MoveTable(programmed)
        for k in range(outline.count):
            p = outline.polyline(k) * 1e3
            ax.plot(p[:, 0], p[:, 1], "--", color="0.35", lw=0.8, label=None if k else "part outline (G41 / G42)")
    feed = rapid = True  # label each kind once
    for k, move in enumerate(plan.moves):
        p = plan.table.polyline(k) * 1e3
        if move.rapid:
            ax.plot(p[:, 0], p[:, 1], ":", color="0.6", lw=0.8, label="rapid (G0)" if rapid else None)
            rapid = False
        else:
            ax.plot(p[:, 0], p[:, 1], color="0.72", lw=2.4, label="programmed path" if feed else None, zorder=3)
            feed = False


def _mark_worst(ax: Any, summary: Any, plan: ProgramPath) -> None:
    """summary.json's worst blocks (a band under the program) and worst corners (circled, labelled)."""
    part = summary.part_error
    if part is None:
        return
    first = True
    for block in part.worst_blocks[:MARKED]:
        for k, move in enumerate(plan.moves):
            if move.line == block.line and not move.rapid:
                p = plan.table.polyline(k) * 1e3
                label = f"worst {MARKED} blocks (band)" if first else None
                ax.plot(p[:, 0], p[:, 1], color="tab:orange", lw=7, alpha=0.35, solid_capstyle="round", label=label)
                first = False
    middle = _geometry_points(plan).mean(axis=0) * 1e3
    for i, corner in enumerate(part.worst_corners[:MARKED]):
        x, y = (1e3 * v for v in corner.point_m)
        label = f"worst {MARKED} corners" if i == 0 else None
        ax.plot(x, y, "o", ms=11, mfc="none", mec="tab:red", mew=1.4, label=label, zorder=5)
        inward = x > middle[0]  # the label towards the part's middle, off the panel's edge
        ax.annotate(
            f"line {corner.line}: {corner.max_um:.1f} µm",
            (x, y),
            xytext=(-8 if inward else 8, 8 if i % 2 == 0 else -14),
            ha="right" if inward else "left",
            textcoords="offset points",
            fontsize=7,
            color="tab:red",
            bbox={"facecolor": "white", "edgecolor": "none", "alpha": 0.8, "pad": 1},
            zorder=6,
        )


def _segments(points_mm: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Segments (m, 2, 2) between consecutive points that are both measured, and each one's value."""
    ok = np.isfinite(values[:-1]) & np.isfinite(values[1:])
    seg = np.stack([points_mm[:-1], points_mm[1:]], axis=1)[ok]
    return seg, np.maximum(values[:-1], values[1:])[ok]


def fig_part(plt: Any, runs: Sequence[Any], name: str = "") -> Any | None:
    """The part figure of the runs that ran a program (``r.part`` a :class:`PartSeries`); None if none did.
    ``name``: the run, in a second line of the title (one run; several are named in their panels)."""
    from matplotlib.collections import LineCollection
    from matplotlib.colors import Normalize

    runs = [r for r in runs if getattr(r, "part", None) is not None]
    if not runs:
        return None
    parts = [r.part for r in runs]
    k = magnification(parts)
    peak_um = max((float(np.nanmax(p.distance_m)) * 1e6 for p in parts if np.isfinite(p.distance_m).any()), default=0)
    norm = Normalize(0.0, peak_um if peak_um > 0 else 1.0)
    shown = runs[:MAX_PANELS]
    fig = plt.figure(figsize=(max(7.5, 5.2 * len(shown)), 9.2))
    grid = fig.add_gridspec(2, len(shown), height_ratios=(3.2, 1), hspace=0.2, wspace=0.18)
    fig.subplots_adjust(left=0.09, right=0.9, bottom=0.06, top=0.855)
    xy_axes = []
    for i, r in enumerate(shown):
        ax = fig.add_subplot(grid[0, i])
        xy_axes.append(ax)
        p = r.part
        _draw_program(ax, p.plan)
        _mark_worst(ax, r.summary, p.plan)
        drawn = (p.nearest_m + k * (p.q_m - p.nearest_m)) * 1e3
        seg, value = _segments(drawn, p.distance_m * 1e6)
        lines = LineCollection(seg, cmap=COLOURS, norm=norm, linewidths=1.6, zorder=4)
        lines.set_array(value)
        ax.add_collection(lines)
        if np.isfinite(p.distance_m).any():
            i_max = int(np.nanargmax(p.distance_m))
            label = f"largest: {p.distance_m[i_max] * 1e6:.1f} µm, t = {p.t_s[i_max]:.2f} s"
            ax.plot(*drawn[i_max], "*", ms=12, mfc="gold", mec="black", mew=0.7, label=label, zorder=6)
        ax.set_aspect("equal", adjustable="datalim")
        ax.autoscale_view()
        ax.set_xlabel("x (mm)")
        if i == 0:
            ax.set_ylabel("y (mm)")
        part = r.summary.part_error
        if part is not None:
            text = f"part error max {part.max_um:.2f} µm, rms {part.rms_um:.2f} µm\ncycle {part.cycle_time_s:.3f} s"
            ax.set_title((r.label + "\n" if len(runs) > 1 else "") + text, fontsize=8)
        ax.legend(loc="upper right", fontsize=6, framealpha=0.85)
    if len(xy_axes) > 1:  # one scale for every run's part: the union of their data limits
        lo = np.min([(a.get_xlim()[0], a.get_ylim()[0]) for a in xy_axes], axis=0)
        hi = np.max([(a.get_xlim()[1], a.get_ylim()[1]) for a in xy_axes], axis=0)
        for a in xy_axes:
            a.set_xlim(lo[0], hi[0])
            a.set_ylim(lo[1], hi[1])
    bar = fig.colorbar(lines, ax=fig.axes, fraction=0.03, pad=0.02, shrink=0.7, anchor=(0.0, 0.8))
    bar.set_label("part error (µm): distance to the programmed lines and arcs", fontsize=8)
    ax_t = fig.add_subplot(grid[1, :])
    for r in runs:
        ax_t.plot(r.part.t_s, r.part.distance_m * 1e6, lw=0.8, label=r.label if len(runs) > 1 else "part error")
    part = runs[0].summary.part_error
    for corner in part.worst_corners[:MARKED] if part is not None else ():
        ax_t.axvline(corner.time_s, color="tab:red", lw=0.7, ls="--")
        ax_t.annotate(f"line {corner.line}", (corner.time_s, 1.0), xycoords=("data", "axes fraction"),
                      xytext=(2, -10), textcoords="offset points", fontsize=6, color="tab:red")  # fmt: skip
    ax_t.set(xlabel="time t (s)", ylabel="part error (µm)")
    ax_t.set_ylim(bottom=0.0)
    ax_t.legend(loc="upper left", fontsize=6)
    heading = f"part error: the actual path q drawn at p + {k:g} (q - p), p its nearest programmed point (the error "
    heading += f"magnified {k:g}x), coloured by the part error |q - p|"
    if len(runs) > len(shown):
        heading += f" (the first {len(shown)} of {len(runs)} runs drawn in XY)"
    fig.suptitle(textwrap.fill(heading, 100) + (f"\n{name}" if name else ""), fontsize=9)
    return fig
