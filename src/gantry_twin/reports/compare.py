"""``gantry-twin compare RUN RUN... [--out DIR]``: the figures of several runs side by side (docs/cli.md).

Each RUN is a run directory (one holding ``summary.json``), ``runs/<name>/latest``,
or ``runs/<name>`` (its ``latest``). The table (printed, and written as
``compare.md`` and ``compare.json``) has a column per run and a row per figure,
each row naming its window: the contour error over the paper's window and
over the whole run after the first period, axial errors, commands and
saturation, rms per period, estimates against the true values, health
alarms, end-stop contacts. The overlay figures (``plots/``, drawn by
:mod:`gantry_twin.outputs.plots` from each run's trace.parquet) are those of a run
with one line per run. A run written by an older gantry-twin lacks some
figures: its cells say ``missing`` and a note under the table names them.
"""

from __future__ import annotations

import json
import math
import textwrap
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gantry_twin.inputs import InputFileError
from gantry_twin.outputs.rundirs import resolve_run
from gantry_twin.outputs.summary import RunSummary, SummaryError
from gantry_twin.plant.model import AXES, THETA_NAMES
from gantry_twin.settings import signed_pct

#: Where compare writes without --out: RUNS_DIR/compare/<UTC time>-<id>/ (RUNS_DIR of the command line).
DEFAULT_SUBDIR = "compare"
#: A run's label in the plots' legends is cut to this many characters.
LABEL_CHARS = 48
MISSING = "missing"
#: An untrusted estimate's cell gives the reason in at most this many characters.
DOUBT_CHARS = 80


class CompareError(Exception):
    """Bad input to compare (exit code 2): one line naming the run directory or file and what is wrong."""


@dataclass(frozen=True)
class Run:
    """One run to compare: its directory, summary.json's content, its column name (``#1``, ``#2``, ...)."""

    directory: Path
    summary: RunSummary
    column: str


def labels(runs: Sequence[Run]) -> list[str]:
    """Legend labels: column, controller and the ``--set`` overrides not common to every run (shortened)."""
    sets = [list(run.summary.overrides or []) for run in runs]
    common = set.intersection(*(set(s) for s in sets)) if sets else set()
    return [
        textwrap.shorten(
            f"{run.column} {run.summary.controller} " + " ".join(o for o in s if o not in common),
            LABEL_CHARS,
            placeholder="...",
        )
        for run, s in zip(runs, sets, strict=True)
    ]


def load_run(arg: str, column: str) -> Run:
    """The run a RUN argument names, its summary read (CompareError if it is not a run directory)."""
    path = Path(arg)
    if not path.exists():
        raise CompareError(f"{arg}: no such run directory")
    try:
        directory = resolve_run(path)
    except OSError as exc:
        raise CompareError(f"{arg}: cannot read it ({exc.strerror or exc})") from None
    except InputFileError as exc:  # a ``latest`` text file that is not one
        raise CompareError(str(exc)) from None
    if not directory.is_dir():
        raise CompareError(f"{arg}: not a run directory (expected a directory holding summary.json)")
    summary_path = directory / "summary.json"
    if not summary_path.is_file():
        raise CompareError(f"{arg}: not a run directory: no summary.json (a run that did not finish?)")
    try:
        summary = RunSummary.read(summary_path)
    except SummaryError as exc:
        raise CompareError(str(exc)) from None
    return Run(directory, summary, column)


def program_plan(run: Run) -> tuple[Any, str | None]:
    """The part program a run ran, read and planned again from the file its scenario.yaml names (for its part
    figure; a run LinuxCNC drove: its recorded commands, :func:`~gantry_twin.scenario.building.recorded_linuxcnc_path`),
    and a note when that cannot be done; (None, None) for a run of another contour."""
    from gantry_twin.scenario import ScenarioError, load_scenario
    from gantry_twin.scenario.building import recorded_linuxcnc_path
    from gantry_twin.scenario.schema import GcodeSpec

    path = run.directory / "scenario.yaml"
    if run.summary.part_error is None or not path.is_file():
        return None, None
    try:
        contour = load_scenario(path).contour
        if isinstance(contour, GcodeSpec) and contour.cnc == "linuxcnc":
            return recorded_linuxcnc_path(contour, run.directory, str(path)), None
        if isinstance(contour, GcodeSpec):
            return contour.plan(run.directory), None
    except (ScenarioError, OSError, ValueError) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        return None, f"{run.column} ({run.directory}): its program cannot be planned again ({reason}), no part figure"
    return None, None


# ---------------------------------------------------------------------------
# The table: one row per figure, a function of a run's summary giving its value (None: missing).


def _get(data: Any, *keys: Any) -> Any:
    """summary.<key>.<key>... through the typed summary (a field or a per-axis / per-parameter key); None if absent."""
    for key in keys:
        if isinstance(data, dict):
            data = data.get(key)
        else:
            data = getattr(data, key, None)
        if data is None:
            return None
    return data


def _window(w: Any) -> str | None:
    return None if w is None else f"[{w[0]:.3f}, {w[1]:.3f}]"


def _estimate(s: RunSummary, name: str) -> Any:
    e = _get(s, "estimates", name)
    if e is None:
        return None
    pct = "" if e.error_pct is None else f" ({signed_pct(e.error_pct, 2)})"
    true = "-" if e.true is None else f"{e.true:.4f}"
    doubt = f"; {textwrap.shorten(e.distrust, DOUBT_CHARS, placeholder=' ...')}" if e.distrust else ""
    return f"{e.estimate:.5f} / {true}{pct}{doubt}"


def _periods(s: RunSummary) -> Any:
    rms = _get(s, "contour_error_per_period_um", "rms")
    if not rms:
        return None
    worst = max(range(len(rms)), key=lambda i: rms[i])
    return f"{rms[0]:.3f} / {rms[-1]:.3f} / {rms[worst]:.3f} (period {worst})"


def _metric_window(s: RunSummary) -> Any:
    c = s.contour_error_um
    if c is None:
        return None
    return _window(c.window_s) + (" (the paper's)" if c.paper_window else "")


def _worst_corner(s: RunSummary) -> Any:
    corners = _get(s, "part_error", "worst_corners")
    if corners is None:
        return None
    if not corners:
        return "-"
    c = corners[0]
    return f"line {c.line} ({c.kind}): {c.max_um:.3f} at {1e3 * c.speed_m_s:.1f} mm/s, t = {c.time_s:.3f} s"


def _alarms(s: RunSummary) -> Any:
    if s.health is None:
        return "no monitor"
    alarms = s.health.alarms
    return f"{len(alarms)}" + (": " + ", ".join(a.parameter for a in alarms) if alarms else "")


#: (row name, the summary.json section it reads (for the missing-figure note), value of a summary).
ROWS: list[tuple[str, str, Callable[[RunSummary], Any]]] = [
    ("scenario", "scenario", lambda s: s.scenario or s.log),
    ("controller", "controller", lambda s: s.controller),
    ("--set overrides", "overrides", lambda s: None if s.overrides is None else " ".join(s.overrides) or "-"),
    ("duration (s)", "duration_s", lambda s: s.duration_s),
    ("status", "status", lambda s: s.status),
    ("metric window window_s (s)", "contour_error_um", _metric_window),
    ("eps_c rms over window_s (um)", "contour_error_um", lambda s: _get(s, "contour_error_um", "rms")),
    ("eps_c max over window_s (um)", "contour_error_um", lambda s: _get(s, "contour_error_um", "max")),
    ("whole run [window_s start, end] (s)", "whole_run", lambda s: _window(_get(s, "whole_run", "window_s"))),
    ("eps_c rms, whole run (um)", "whole_run", lambda s: _get(s, "whole_run", "contour_error_um", "rms")),
    ("eps_c max, whole run (um)", "whole_run", lambda s: _get(s, "whole_run", "contour_error_um", "max")),
    *[
        (f"e_{a} rms, whole run (um)", "whole_run", lambda s, a=a: _get(s, "whole_run", "axial_error_rms_um", a))
        for a in AXES
    ],
    ("command window (s)", "whole_run", lambda s: _window(_get(s, "whole_run", "command_window_s"))),
    *[
        (
            f"max abs(u_{a}), command window (V)",
            "whole_run",
            lambda s, a=a: _get(s, "whole_run", "max_abs_command_v", a),
        )
        for a in AXES
    ],
    *[
        (
            f"u_{a} at its limit, whole run (%)",
            "saturation",
            lambda s, a=a: None if _get(s, "saturation", a) is None else 100.0 * s.saturation[a].fraction,
        )
        for a in AXES
    ],
    ("eps_c rms per period: first / last / largest (um)", "contour_error_per_period_um", _periods),
    ("part error max, to the programmed geometry (um)", "part_error", lambda s: _get(s, "part_error", "max_um")),
    ("part error rms (um)", "part_error", lambda s: _get(s, "part_error", "rms_um")),
    ("worst corner: part error (um), speed, time", "part_error", _worst_corner),
    ("cycle time (s)", "part_error", lambda s: _get(s, "part_error", "cycle_time_s")),
    (
        "feed achieved (mm/s)",
        "part_error",
        lambda s: None if s.part_error is None else 1e3 * s.part_error.feed_achieved_m_s,
    ),
    ("estimates window (s)", "estimates", lambda s: _window(s.estimates_window_s)),
    *[(f"{n} estimate / true (error)", "estimates", lambda s, n=n: _estimate(s, n)) for n in THETA_NAMES],
    ("health alarms", "health", _alarms),
    (
        "end-stop contacts",
        "end_stop_contacts",
        lambda s: (
            None if s.end_stop_contacts is None else ", ".join(f"{a} {n}" for a, n in s.end_stop_contacts.items())
        ),
    ),
]


def _why_absent(s: RunSummary, section: str) -> str | None:
    """Why a run has no value for a row: None when the figure should be there (then it is missing)."""
    if s.failed and section in (
        "contour_error_um",
        "whole_run",
        "contour_error_per_period_um",
        "estimates",
    ):
        return "- (failed run)"
    if section == "estimates" and s.contour_error_um is not None and s.estimates is None:
        return "- (not estimated)"
    if section == "part_error" and s.part_error is None:
        return "- (not a part program)"
    if section == "contour_error_per_period_um" and s.part_error is not None:
        return "- (a part program: no lap)"
    return None


def table(runs: Sequence[Run]) -> tuple[list[tuple[str, list[Any]]], list[str]]:
    """The rows (name, one value per run) and the notes naming each run's missing figures."""
    rows, missing = [], {run.column: [] for run in runs}
    for name, section, value in ROWS:
        cells = []
        for run in runs:
            v = value(run.summary)
            if v is None:
                v = _why_absent(run.summary, section)
            if v is None:
                v = MISSING
                missing[run.column].append(name)
            cells.append(v)
        rows.append((name, cells))
    notes = [
        f"{run.column} ({run.directory}): summary.json lacks {', '.join(missing[run.column])} "
        f"(written by an older gantry-twin?)"
        for run in runs
        if missing[run.column]
    ]
    return rows, notes


def _cell(v: Any) -> str:
    if isinstance(v, float):
        return "-" if math.isnan(v) else f"{v:.3f}"
    return str(v)


def markdown(runs: Sequence[Run], rows: list[tuple[str, list[Any]]], notes: list[str]) -> str:
    """The table as Markdown, the run directories above it and the notes below."""
    lines = ["# Runs compared", ""]
    lines += [f"- **{run.column}**: `{run.directory}`" for run in runs]
    lines += ["", "| figure (window) | " + " | ".join(run.column for run in runs) + " |"]
    lines.append("|---" * (len(runs) + 1) + "|")
    lines += [f"| {name} | " + " | ".join(_cell(v).replace("|", "\\|") for v in cells) + " |" for name, cells in rows]
    if notes:
        lines += ["", "Notes:", "", *[f"- {n}" for n in notes]]
    return "\n".join(lines) + "\n"


def as_json(runs: Sequence[Run], rows: list[tuple[str, list[Any]]], notes: list[str]) -> str:
    data = {
        "runs": [
            {"column": run.column, "directory": str(run.directory), "figures": {n: c[i] for n, c in rows}}
            for i, run in enumerate(runs)
        ],
        "missing": notes,
    }
    return json.dumps(data, indent=2, allow_nan=False) + "\n"
