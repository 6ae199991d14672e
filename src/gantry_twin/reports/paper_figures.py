"""The report's figures (Figs. 2-5 of the paper), drawn from the matrix's results (:mod:`gantry_twin.reports.paper`).

Figs. 2 and 3: eps_c(t) per controller on one y scale, the metric window
shaded and the disturbance events marked; Figs. 4 and 5: the estimates of one
axis with the true value dashed, the runs whose trust verdict does not vouch
for a panel's estimate named above it. PNG at
:data:`gantry_twin.outputs.plots.DPI`.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

from gantry_twin.outputs.files import atomic_write
from gantry_twin.outputs.plots import DPI, legend_below
from gantry_twin.plant.model import THETA_NAMES, THETA_UNITS

#: Height of one row of a legend below the panels (font size 7), inches.
LEGEND_ROW_IN = 0.17
#: The runs of Figs. 4-5 by the estimator they differ in.
ESTIMATOR_NAMES = {"C2": "paper estimator", "C2r": "recommended estimator"}


def write_figures(by_key: dict[tuple[int, str, str], Any], out: Path, legend: dict[str, str]) -> list[tuple[str, str]]:
    """Write :func:`figures` as PNG files into ``out``; (file name, caption) of each."""
    import matplotlib.pyplot as plt

    made: list[tuple[str, str]] = []
    for fig, name, caption in figures(by_key, legend):
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=DPI)
        plt.close(fig)
        data = buffer.getvalue()
        atomic_write(out / name, lambda fh, data=data: fh.write(data))
        made.append((name, caption))
    return made


def _mark_events(ax: Any, r: Any, t_end: float, label: bool) -> None:
    """The metric window shaded and each disturbance event's interval hatched, labelled for what they are."""
    w0, w1 = r.window_s
    ax.axvspan(
        w0, min(w1, t_end), color="0.9", zorder=0, label=f"metric window [{w0:.2f}, {w1:.2f}] s" if label else None
    )
    for start, end, what in r.disturbances:
        stop = t_end if end is None else min(end, t_end)
        span = f"[{start:g}, {'end' if end is None else f'{end:g}'})"
        ax.axvspan(start, stop, facecolor="none", edgecolor="tab:red", hatch="//", lw=0, alpha=0.35,
                   label=f"disturbance: {what}, {span} s" if label else None)  # fmt: skip


def _below(fig: Any, rows: int) -> None:
    """Lay the panels out above ``rows`` rows of a legend at the figure's bottom (:func:`legend_below`)."""
    fig.tight_layout(rect=(0.0, (0.1 + LEGEND_ROW_IN * rows) / fig.get_figheight(), 1.0, 1.0))


def figures(by_key: dict[tuple[int, str, str], Any], legend: dict[str, str]) -> list[tuple[Any, str, str]]:
    """The report's figures (matplotlib, Agg) as (figure, file name, caption); every axis label gives its unit.
    ``by_key``: the matrix's results (:class:`~gantry_twin.reports.paper.CaseResult`) by (set, contour,
    label); ``legend``: each label's legend name (``C2``: ``DIARC, paper estimator (...)``).

    Figs. 2 and 3 share one y scale across the controllers they compare;
    the estimate plots (Figs. 4 and 5) keep a 10 % margin around the
    estimates and the true value.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    made: list[tuple[Any, str, str]] = []

    for fig_no, set_id, contour, labels in ((2, 3, "circle", ("C1", "C2")), (3, 2, "ellipse", ("C1", "C2", "C3"))):
        runs = [(c, by_key.get((set_id, contour, c))) for c in labels]
        runs = [(c, r) for c, r in runs if r is not None]
        if not runs:
            continue
        fig, axes = plt.subplots(
            len(runs), 1, figsize=(7.5, 1.9 * len(runs) + 0.9), sharex=True, sharey=True, squeeze=False
        )
        t_end = min(10.0, max(float(r.t_eps_s[-1]) for _, r in runs))
        for i, (ax, (c, r)) in enumerate(zip(axes[:, 0], runs, strict=True)):
            keep = r.t_eps_s <= t_end
            _mark_events(ax, r, t_end, label=i == 0)
            ax.plot(r.t_eps_s[keep], r.eps_c_um[keep], lw=0.6, color="tab:blue")
            ax.set_ylabel(f"{c} eps_c [µm]")
            ax.grid(alpha=0.3)
        axes[-1, 0].set_xlabel("t [s]")
        fig.suptitle(f"Fig. {fig_no}: {contour} contouring errors, Set {set_id} (largest |eps_c| per 2 ms)")
        _below(fig, legend_below(fig, axes[0, 0]))
        made.append(
            (
                fig,
                f"fig{fig_no}_set{set_id}_{contour}_contour_error.png",
                f"Fig. {fig_no}: {contour} contouring error vs time, Set {set_id} (largest |eps_c| per 2 ms)",
            )
        )

    for fig_no, set_id, axis in ((4, 1, 1), (5, 2, 0)):
        runs = [(c, by_key.get((set_id, "circle", c))) for c in ("C2", "C2r")]
        runs = [(c, r) for c, r in runs if r is not None and r.theta_hat is not None]
        if not runs:
            continue
        names = [THETA_NAMES[axis + 2 * k] for k in range(4)]
        fig, axes = plt.subplots(4, 1, figsize=(7.5, 8.4), sharex=True)
        for k, (ax, name) in enumerate(zip(axes, names, strict=True)):
            j = axis + 2 * k
            for c, r in runs:
                ax.plot(r.t_theta_s, r.theta_hat[:, j], lw=0.9, label=legend[c])
            ax.axhline(runs[0][1].true_theta[j], ls="--", color="k", lw=0.9, label="true (model)")
            ax.set_ylabel(f"{name} [{THETA_UNITS[j]}]")
            ax.margins(y=0.1)
            ax.ticklabel_format(axis="y", useOffset=False)
            ax.grid(alpha=0.3)
            doubts = [ESTIMATOR_NAMES.get(c, c) for c, r in runs if name in r.distrust]
            if doubts:  # the reasons are listed under Tables 3-4 of report.md
                note = f"{name} not trusted: {', '.join(doubts)} (why: report.md, under Tables 3-4)"
                ax.set_title(note, fontsize=7, color="0.35", loc="left", pad=2)
        axes[-1].set_xlabel("t [s]")
        label = "Y" if axis == 1 else "X"
        fig.suptitle(f"Fig. {fig_no}: {label}-axis parameter estimates, Set {set_id} circle (DIARC)")
        _below(fig, legend_below(fig, axes[0], ncol=1))  # in a panel ("best") it covered Fig. 5's M1 estimate
        made.append(
            (
                fig,
                f"fig{fig_no}_set{set_id}_{label.lower()}_estimates.png",
                f"Fig. {fig_no}: {label}-axis estimates vs time, Set {set_id} circle; true value dashed",
            )
        )
    return made
