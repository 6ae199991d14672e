"""The paper-reproduction report: Tables 1-4 and Fig. 2-5 of Hu, Yao, Wang (2010).

The matrix: C1 DARC, C2 DIARC (paper estimator), C3 DRC on the circle and the
ellipse for Set 1 (no load), Set 2 (5 kg) and Set 3 (step disturbance; no C3,
as in the paper): 16 runs; plus DIARC with the twin's recommended estimator
(10 Hz filters, sign friction, reversal gate; docs/estimator-envelope.md) on
Sets 1-2: 4 runs. Each run is a shipped scenario with the controller
replaced; runs go to a local Dask cluster, the engine of ``gantry-twin
sweep`` (:mod:`gantry_twin.sweep.engine`).

Reading of "after running the gantry for one period" (the paper says no more; docs/scenarios.md):
contour metrics of Sets 1-2 cover the second period [T, 2T] of a run started
on the path; Set 3's cover [1.5, 6.5] s (both disturbance edges); steady
estimates are the mean of theta^ over the last period of the 30 s run.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gantry_twin.metrics import contour_metrics, error_pct, steady_estimates, steady_true_parameters
from gantry_twin.outputs.files import atomic_write_text
from gantry_twin.outputs.plots import envelope
from gantry_twin.plant.model import THETA_NAMES, short_label
from gantry_twin.reports.paper_figures import write_figures
from gantry_twin.run import execute, summarise
from gantry_twin.scenario import build, load_scenario, shipped
from gantry_twin.settings import signed_pct
from gantry_twin.theta import NOMINAL_THETA

SET_SCENARIOS = {1: "no_load", 2: "load_5kg", 3: "step_disturbance"}
CONTOURS = ("circle", "ellipse")
#: Column label -> (controller, extra --set overrides, description).
CONTROLLERS: dict[str, tuple[str, tuple[str, ...], str]] = {
    "C1": ("darc", (), "DARC"),
    "C2": ("diarc", ("controller.options.estimator=paper",), "DIARC, paper estimator (250/150 Hz filters)"),
    "C3": ("drc", (), "DRC"),
    "C2r": (
        "diarc",
        ("controller.options.estimator=recommended",),
        "DIARC, recommended estimator (10 Hz filters, sign friction)",
    ),
}

#: Paper Tables 1-2: (contour, set, controller) -> (rms um, max um).
PAPER_CONTOUR_UM: dict[tuple[str, int, str], tuple[float, float]] = {
    ("circle", 1, "C1"): (2.03, 7.31),
    ("circle", 1, "C2"): (1.99, 7.14),
    ("circle", 1, "C3"): (7.33, 21.0),
    ("circle", 2, "C1"): (2.18, 8.16),
    ("circle", 2, "C2"): (2.02, 6.85),
    ("circle", 2, "C3"): (8.36, 19.78),
    ("circle", 3, "C1"): (2.36, 26.81),
    ("circle", 3, "C2"): (2.30, 28.43),
    ("ellipse", 1, "C1"): (2.63, 9.35),
    ("ellipse", 1, "C2"): (2.61, 8.19),
    ("ellipse", 1, "C3"): (7.00, 18.17),
    ("ellipse", 2, "C1"): (2.89, 10.31),
    ("ellipse", 2, "C2"): (2.66, 8.96),
    ("ellipse", 2, "C3"): (11.4, 30.1),
    ("ellipse", 3, "C1"): (3.10, 25.4),
    ("ellipse", 3, "C2"): (2.91, 26.0),
}
#: Paper Tables 3-4 (set -> rows theta_iN, theta_iC, theta_ie, theta_iv %), M1 M2 B1 B2 Af1 Af2.
PAPER_ESTIMATES: dict[int, dict[str, tuple[float, ...]]] = {
    1: {
        "nominal": NOMINAL_THETA[:6],
        "circle": (0.111, 0.483, 0.522, 0.730, 0.102, 0.150),
        "ellipse": (0.115, 0.505, 0.464, 0.670, 0.104, 0.147),
        "pct": (7.5, 3.4, 7.2, 4.3, 4.0, 2.0),
    },
    2: {
        "nominal": (0.19, 0.57, 0.5, 0.7, 0.1, 0.15),
        "circle": (0.182, 0.562, 0.500, 0.642, 0.102, 0.163),
        "ellipse": (0.188, 0.578, 0.462, 0.720, 0.105, 0.15),
        "pct": (4.2, 1.4, 7.6, 8.3, 5.0, 8.7),
    },
}
#: The physical parameters the paper's Tables 3-4 report (dN is left out, as there).
TABLE_PARAMS = THETA_NAMES[:6]
#: After an estimate in Tables 3-4 that its run's trust verdict does not vouch for (the reasons under the table).
DISTRUST_MARK = "†"
_TABLE_INDEX = range(len(TABLE_PARAMS))
#: Figure sampling: eps_c keeps the largest |value| of each bin; estimates every n-th sample.
EPS_BIN = 10
THETA_EVERY = 25


@dataclass(frozen=True)
class Case:
    """One run of the matrix: a shipped scenario with a controller."""

    set_id: int
    contour: str
    label: str
    scenario_path: str
    controller: str
    overrides: tuple[str, ...]

    @property
    def key(self) -> str:
        return f"set{self.set_id}_{self.contour}_{self.label}"


@dataclass
class CaseResult:
    """What the report needs from one run (figure series decimated)."""

    case: Case
    rms_um: float
    max_um: float
    window_s: tuple[float, float]
    steps: int
    wall_time_s: float
    true_theta: list[float]  # mean over estimates_window_s (volt units), what the estimates are judged against
    estimates: list[float] | None
    estimates_window_s: tuple[float, float]
    t_eps_s: np.ndarray = field(repr=False)
    eps_c_um: np.ndarray = field(repr=False)
    t_theta_s: np.ndarray | None = field(default=None, repr=False)
    theta_hat: np.ndarray | None = field(default=None, repr=False)
    #: The estimates summary.json would not trust (name -> ``not trusted: why``, :attr:`Estimate.distrust`).
    distrust: dict[str, str] = field(default_factory=dict)
    #: The scenario's disturbance events: (start s, end s or None, what), for the figures.
    disturbances: list[tuple[float, float | None, str]] = field(default_factory=list)


def paper_matrix(
    overrides: Sequence[str] = (),
    sets: Sequence[int] = (1, 2, 3),
    contours: Sequence[str] = CONTOURS,
    labels: Sequence[str] = ("C1", "C2", "C3", "C2r"),
) -> list[Case]:
    """The report's runs, each validated (ScenarioError on a bad override) before any runs."""
    cases = []
    for set_id in sets:
        for contour in contours:
            for label in labels:
                if not _in_matrix(set_id, label):
                    continue
                controller, extra, _ = CONTROLLERS[label]
                path = shipped(f"{SET_SCENARIOS[set_id]}_{contour}")
                case = Case(set_id, contour, label, str(path), controller, (*extra, *overrides))
                build(load_case(case), case.scenario_path)
                cases.append(case)
    return cases


def _in_matrix(set_id: int, label: str) -> bool:
    """Set 3 (the step disturbance) runs C1 and C2 only, as in the paper."""
    return set_id != 3 or label in ("C1", "C2")


def load_case(case: Case) -> Any:
    """The scenario of a case, as ``gantry-twin run`` would load it."""
    return load_scenario(case.scenario_path, case.overrides, case.controller)


def run_case(case: Case) -> CaseResult:
    """Run one case (in a worker process: its loop compiled or loaded first, once) and keep what the report needs."""
    from gantry_twin.sweep.engine import warm_up

    scenario = load_case(case)
    warm_up(scenario, case.scenario_path)
    built = build(scenario, case.scenario_path)
    started = time.perf_counter()
    trace = execute(built)
    wall = time.perf_counter() - started
    metrics = contour_metrics(trace, scenario.metric_window_s)
    est = steady_estimates(trace, scenario.estimate_window_s)
    t_eps, eps = envelope(trace.t_s[: trace.filled], trace.eps_c_m[: trace.filled] * 1e6, EPS_BIN)
    theta = trace.controller_state.get("theta_hat")
    verdicts = summarise(built, trace).estimates or {}  # the trust verdicts, as summary.json gives them
    return CaseResult(
        case=case,
        rms_um=metrics.rms_um,
        max_um=metrics.max_um,
        window_s=metrics.window_s,
        steps=trace.filled,
        wall_time_s=wall,
        true_theta=[float(v) for v in steady_true_parameters(trace, scenario.estimate_window_s)],
        estimates=None if est is None else [float(v) for v in est],
        estimates_window_s=scenario.estimate_window_s,
        t_eps_s=t_eps,
        eps_c_um=eps,
        t_theta_s=None if theta is None else trace.t_s[::THETA_EVERY].copy(),
        theta_hat=None if theta is None else theta[::THETA_EVERY].copy(),
        distrust={name: e.distrust for name, e in verdicts.items() if e.distrust},
        disturbances=disturbance_intervals(scenario),
    )


def disturbance_intervals(scenario: Any) -> list[tuple[float, float | None, str]]:
    """Each disturbance event of a scenario: (start s, end s or None: to the end, ``+0.6 V step on Y``)."""
    out = []
    for axis in ("x", "y"):
        for e in getattr(scenario.disturbance, axis):
            size = {"step": "value_v", "ramp": "to_v", "sine": "amplitude_v"}[e.type]
            out.append((e.start_s, e.end_s, f"{getattr(e, size):+g} V {e.type} on {axis.upper()}"))
    return out


def run_matrix(cases: Sequence[Case], jobs: int = 1, progress: bool = False) -> list[CaseResult]:
    """Run every case, a named point, on the batch runner (a local cluster of ``jobs`` processes, as a sweep
    runs): results in case order."""
    from gantry_twin.outputs.signals import stop_signals_interrupt
    from gantry_twin.sweep.engine import run_all

    if not cases:
        return []
    resolved = [load_case(case).resolved() for case in cases]
    with stop_signals_interrupt():
        workers = max(1, min(jobs, len(cases)))
        return run_all(
            run_case, [(case,) for case in cases], resolved, cases[0].scenario_path, workers, None, progress, "report"
        )


# ---------------------------------------------------------------------------
# The Markdown report.


def _fmt(x: float | None, digits: int = 2) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def provenance(command: str, wall_time_s: float, version: str, now_s: float | None = None) -> str:
    """The report's provenance line: the gantry-twin version, the UTC date, the command line and the wall time."""
    import time

    date = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(time.time() if now_s is None else now_s))
    return f"Made by gantry-twin {version} on {date} with `{command}` in {wall_time_s:.0f} s of wall time."


def _contour_table(by_key: dict[tuple[int, str, str], CaseResult], contour: str, twin: str = "twin") -> list[str]:
    columns = [(s, c) for s in (1, 2, 3) for c in ("C1", "C2", "C3") if _in_matrix(s, c)]
    head = "| | " + " | ".join(f"Set {s} {c}" for s, c in columns) + " |"
    lines = [head, "|---" * (len(columns) + 1) + "|"]
    for what, index in (("rms", 0), ("max", 1)):
        paper = [PAPER_CONTOUR_UM.get((contour, s, c), (None, None))[index] for s, c in columns]
        twin_results = [by_key.get((s, contour, c)) for s, c in columns]
        values = [None if r is None else (r.rms_um if index == 0 else r.max_um) for r in twin_results]
        lines.append(f"| {what} paper (um) | " + " | ".join(_fmt(v) for v in paper) + " |")
        lines.append(f"| **{what} {twin} (um)** | " + " | ".join(f"**{_fmt(v)}**" for v in values) + " |")
    return lines


def _estimate_table(by_key: dict[tuple[int, str, str], CaseResult], set_id: int) -> list[str]:
    head = "| | " + " | ".join(TABLE_PARAMS) + " |"
    lines = [head, "|---" * (len(TABLE_PARAMS) + 1) + "|"]
    doubts: list[str] = []
    paper = PAPER_ESTIMATES[set_id]
    lines.append("| *paper:* nominal theta_iN | " + " | ".join(f"{v:g}" for v in paper["nominal"]) + " |")
    lines.append("| *paper:* circle theta_iC | " + " | ".join(f"{v:g}" for v in paper["circle"]) + " |")
    lines.append("| *paper:* ellipse theta_ie | " + " | ".join(f"{v:g}" for v in paper["ellipse"]) + " |")
    lines.append("| *paper:* max deviation % | " + " | ".join(f"{v:g} %" for v in paper["pct"]) + " |")
    for label in ("C2", "C2r", "C1"):
        runs = [by_key.get((set_id, contour, label)) for contour in CONTOURS]
        runs_ok = [r for r in runs if r is not None and r.estimates is not None]
        if not runs_ok:
            continue
        name = {"C2": "DIARC paper settings", "C2r": "DIARC recommended", "C1": "DARC"}[label]
        true = runs_ok[0].true_theta
        lines.append(f"| **{name}:** true (model) | " + " | ".join(f"{true[i]:.4f}" for i in _TABLE_INDEX) + " |")
        for contour, r in zip(CONTOURS, runs, strict=True):
            if r is None or r.estimates is None:
                continue
            cells = [
                f"{r.estimates[i]:.4f} ({signed_pct(error_pct(r.estimates[i], true[i]))})"
                + (f" {DISTRUST_MARK}" if THETA_NAMES[i] in r.distrust else "")
                for i in _TABLE_INDEX
            ]
            lines.append(f"| {name}: {contour} | " + " | ".join(cells) + " |")
            doubts += [f"{name}, {contour}: {n} {why}" for n, why in r.distrust.items() if n in TABLE_PARAMS]
        worst = [max(abs(error_pct(r.estimates[i], true[i])) for r in runs_ok) for i in _TABLE_INDEX]
        lines.append(f"| {name}: max deviation % | " + " | ".join(f"{w:.1f} %" for w in worst) + " |")
    if doubts:
        why = "the run's own signals cannot vouch for the estimate (summary.json's trust verdict, docs/health.md)"
        lines += ["", f"{DISTRUST_MARK}: {why}:", "", *[f"- {d}" for d in doubts]]
    return lines


def findings(by_key: dict[tuple[int, str, str], CaseResult]) -> list[tuple[bool, str]]:
    """The paper's findings checked on the twin's numbers."""
    out: list[tuple[bool, str]] = []
    for contour in CONTOURS:
        for s in (1, 2):
            c1, c2, c3 = (by_key.get((s, contour, c)) for c in ("C1", "C2", "C3"))
            if c1 and c2:
                ratio = max(c1.rms_um, c2.rms_um) / min(c1.rms_um, c2.rms_um)
                out.append(
                    (
                        ratio <= 1.4,
                        f"{contour} Set {s}: C1 and C2 rms within 40 % of each other "
                        f"({c1.rms_um:.2f} vs {c2.rms_um:.2f} um, ratio {ratio:.2f})",
                    )
                )
            if c1 and c2 and c3:
                worst = max(c1.rms_um, c2.rms_um)
                out.append(
                    (
                        c3.rms_um >= 2.0 * worst,
                        f"{contour} Set {s}: C3 rms at least twice C1's and C2's "
                        f"({c3.rms_um:.2f} um vs {worst:.2f} um, x{c3.rms_um / worst:.2f})",
                    )
                )
        for c in ("C1", "C2"):
            r1, r3 = by_key.get((1, contour, c)), by_key.get((3, contour, c))
            if r1 and r3:
                out.append(
                    (
                        r3.max_um >= 3.0 * r1.max_um,
                        f"{contour} {c}: Set 3 max at least 3x Set 1's "
                        f"({r3.max_um:.2f} vs {r1.max_um:.2f} um, x{r3.max_um / r1.max_um:.2f})",
                    )
                )
            if r3:
                out.append((r3.rms_um < 4.0, f"{contour} {c}: Set 3 rms below 4 um ({r3.rms_um:.2f} um)"))
    for s in (1, 2):
        runs = [by_key.get((s, contour, "C2r")) for contour in CONTOURS]
        runs = [r for r in runs if r is not None and r.estimates is not None]
        if runs:
            worst = max(abs(error_pct(r.estimates[i], r.true_theta[i])) for r in runs for i in _TABLE_INDEX)
            out.append(
                (
                    worst <= 5.0,
                    f"Set {s}: DIARC recommended estimates of M, B, Af within 5 % (largest deviation {worst:.1f} %)",
                )
            )
    return out


def write_report(
    results: Sequence[CaseResult],
    out: Path,
    overrides: Sequence[str] = (),
    appendix: Sequence[str] = (),
    made_by: str = "",
    plant: str = "",
) -> Path:
    """Write report.md, results.json and the PNG figures into ``out``; returns report.md's path.

    ``appendix``: Markdown lines put after the figures (the paper / rig twin / ideal twin section:
    :func:`gantry_twin.reports.rig.section`); ``made_by``: the provenance line under the title
    (:func:`provenance`); ``plant``: the runs' plant in words, named in the tables and results.json.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    by_key = {(r.case.set_id, r.case.contour, r.case.label): r for r in results}
    figures = write_figures(by_key, out, {label: c[2] for label, c in CONTROLLERS.items()})
    checks = findings(by_key)
    lines = [
        "# gantry-twin: reproduction of Hu, Yao, Wang (Automatica 2010), Tables 1-4 and Fig. 2-5",
        "",
        *([made_by, ""] if made_by else []),
        f"{len(results)} runs: C1 = DARC, C2 = DIARC with the paper's estimator settings, C3 = DRC; "
        "C2r = DIARC with the twin's recommended estimator (10 Hz filters, sign friction). Set 1: no load; Set 2: 5 kg "
        "payload; Set 3: +0.6 V on the Y input from 1.86 s to 4.86 s.",
        "",
        *([f"Every twin number in Tables 1-4 and the figures comes from the {plant}.", ""] if plant else []),
        '**Reading of "after running the gantry for one period"** (the paper says no more): every run starts '
        "on the path (as if already running) and lasts 30 s unless overridden."
        " The contour metrics of Sets 1-2 cover the second "
        "period [T, 2T] (T = pi s circle, 2 pi/3 s ellipse); Set 3's cover [1.5, 6.5] s, holding both "
        "disturbance edges. The steady-state estimates (Tables 3-4) are the mean of theta^ over the last "
        "period of the run. Set 3 is not used to judge estimates.",
        "",
    ]
    if overrides:
        lines += [f"Overrides applied to every run: `{' '.join(overrides)}`.", ""]
    lines += ["## Findings checked", ""]
    if checks:
        lines += [f"{sum(ok for ok, _ in checks)} of {len(checks)} findings hold.", ""]
    lines += [f"- {'PASS' if ok else 'FAIL'}: {text}" for ok, text in checks] or ["- (no complete set to check)"]
    for number, contour in ((1, "circle"), (2, "ellipse")):
        lines += ["", f"## Table {number}: {contour} contouring, ||eps_c||_rms and eps_cM (um)", ""]
        lines += _contour_table(by_key, contour, "twin" if not plant else f"twin, {short_label(plant)}")
    for number, set_id, what in ((3, 1, "without load"), (4, 2, "with 5 kg load")):
        lines += [
            "",
            f"## Table {number}: physical parameter estimates {what} (Set {set_id})",
            "",
            "Estimates are the mean over the last period; % is the deviation from the model's true value "
            "(the paper's % is from its off-line estimates).",
            "",
        ]
        lines += _estimate_table(by_key, set_id)
    lines += ["", "## Figures", ""]
    lines += [f"![{caption}]({name})\n\n{caption}\n" for name, caption in figures]
    lines += appendix
    lines += ["## Runs", "", "| run | steps | rms (um) | max (um) | window (s) | wall time (s) |", "|---" * 6 + "|"]
    for r in results:
        lines.append(
            f"| {r.case.key} | {r.steps} | {r.rms_um:.3f} | {r.max_um:.3f} | "
            f"[{r.window_s[0]:.3f}, {r.window_s[1]:.3f}] | {r.wall_time_s:.1f} |"
        )
    path = out / "report.md"
    numbers = [
        {
            **asdict(r.case),
            "key": r.case.key,
            "rms_um": r.rms_um,
            "max_um": r.max_um,
            "window_s": list(r.window_s),
            "steps": r.steps,
            "true_theta": r.true_theta,
            "estimates": r.estimates,
            "estimates_window_s": list(r.estimates_window_s),
            "not_trusted": r.distrust,
        }
        for r in results
    ]
    atomic_write_text(
        out / "results.json",
        json.dumps(
            {"plant": plant, "runs": numbers, "findings": [{"pass": ok, "text": text} for ok, text in checks]},
            indent=2,
        )
        + "\n",
    )
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path
