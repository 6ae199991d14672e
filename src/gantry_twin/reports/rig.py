"""The paper's matrix on the rig twin beside the ideal twin, cell by cell (docs/rig-plant.md).

``gantry-twin report`` runs the report's matrix (:mod:`gantry_twin.reports.paper`)
on the scenarios' plant (the rig plant, models/rig.xml, unless told
otherwise; ``--rig FILE`` puts FILE's ``overrides``, the list that
``gantry-twin calibrate`` writes into ``fit.json``, after each case's own) and
C1-C3 a second time on the ideal twin (``plant.model=paper``, the paper's
model), and adds to report.md a section with paper / rig twin / ideal twin
for every cell of Tables 1-2, the rig twin's error per cell (circle Set 1 is
the calibration's fit, the other cells validation), the acceptance checks on
the rig twin's numbers (docs/rig-plant.md), and a figure of eps_c +-50 ms around
an X reversal of circle Set 1 for C1-C3, rig and ideal twin
(``rig_reversal_spike.png``), and writes the rig runs' numbers to
``rig.json``. :func:`monitor_alarms` counts the health monitor's alarms over long runs.
"""

from __future__ import annotations

import io
import json
import textwrap
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from gantry_twin.inputs import InputFileError, read_input_file
from gantry_twin.metrics import error_pct
from gantry_twin.outputs.files import atomic_write, atomic_write_text
from gantry_twin.outputs.plots import DPI
from gantry_twin.paths.contours import reference
from gantry_twin.plant.model import THETA_NAMES, PlantSettings
from gantry_twin.reports.paper import CONTOURS, CONTROLLERS, PAPER_CONTOUR_UM, SET_SCENARIOS, Case, CaseResult
from gantry_twin.run import execute
from gantry_twin.scenario import BuiltRun, ScenarioError, build, load_scenario, shipped
from gantry_twin.settings import signed_pct

LABELS = ("C1", "C2", "C3")
#: The override that makes the ideal twin: the paper's model (models/gantry.xml), Coulomb friction, no offset
#: and no ripple.
IDEAL = ("plant.model=paper",)
#: The cells the calibration fitted (contour, set): circle Set 1 (calibrations/paper_circle_set1.yaml);
#: the rest validate.
FIT_CELLS = {("circle", 1)}
#: The rig's acceptance (docs/rig-plant.md): at least VALIDATION_TARGET of the 26 validation numbers within
#: VALIDATION_PCT of the paper.
VALIDATION_PCT = 30.0
VALIDATION_TARGET = 22
VALIDATION_NUMBERS = 26
#: C3's rms at least this many times C1's and C2's; DIARC's rms at most this many times DARC's.
C3_OVER_C1_C2 = 2.5
C2_OVER_C1 = 1.05
#: DIARC's recommended estimates within these % of the true values (M, B, Af), and dN within DN_TOL_V, V.
ESTIMATE_PCT = {"M": 3.0, "B": 10.0, "Af": 10.0}
DN_TOL_V = 0.01
#: The reversal-spike figure: +- this much around the first X reversal after the metric window's start, s.
SPIKE_HALF_S = 0.05
SPIKE_FILE = "rig_reversal_spike.png"
#: The rig runs' numbers (rms, max um; estimates), beside the report's results.json.
RIG_JSON = "rig.json"

Key = tuple[int, str, str]


def load_rig(path: Path) -> list[str]:
    """The scenario overrides that make the rig plant: FILE's ``overrides``, a list of ``field=value`` strings."""
    try:  # the input door: a regular file (a FIFO or /dev/zero refused unopened) of at most 256 KiB, UTF-8
        data = json.loads(read_input_file(path, "a rig file (JSON with 'overrides')"))
    except InputFileError as exc:
        raise ScenarioError(str(path), "", str(exc)) from None
    except json.JSONDecodeError as exc:
        raise ScenarioError(str(path), "", f"not JSON ({exc.msg}, line {exc.lineno})") from None
    except RecursionError:
        raise ScenarioError(str(path), "", "not a rig file: JSON nested too deeply") from None
    overrides = data.get("overrides") if isinstance(data, dict) else None
    if not isinstance(overrides, list) or not overrides or not all(isinstance(o, str) for o in overrides):
        raise ScenarioError(str(path), "overrides", "must be a non-empty list of 'field=value' strings")
    return overrides


def rig_cases(cases: Sequence[Case], rig: Sequence[str], labels: Sequence[str] | None = None) -> list[Case]:
    """The same cases (those of ``labels``, default all) with the overrides ``rig`` after their own (each
    validated, as :func:`paper_matrix` does); ``rig_cases(cases, IDEAL, LABELS)`` is the ideal twin's matrix."""
    out = []
    for case in cases:
        if labels is not None and case.label not in labels:
            continue
        rigged = replace(case, overrides=(*case.overrides, *rig))
        build(load_scenario(rigged.scenario_path, rigged.overrides, rigged.controller), rigged.scenario_path)
        out.append(rigged)
    return out


def by_key(results: Sequence[CaseResult]) -> dict[Key, CaseResult]:
    return {(r.case.set_id, r.case.contour, r.case.label): r for r in results}


def cell_errors_pct(rig: CaseResult, paper: tuple[float, float]) -> tuple[float, float]:
    """The rig's error against the paper, rms and max, %."""
    return (rig.rms_um / paper[0] - 1.0) * 100.0, (rig.max_um / paper[1] - 1.0) * 100.0


def matrix_table(rig: dict[Key, CaseResult], ideal: dict[Key, CaseResult]) -> list[str]:
    """Paper / rig twin / ideal twin (rms / max, um) and the rig twin's error per cell that both runs have."""
    lines = [
        "| contour | set | ctrl | paper rms / max | rig twin rms / max | ideal twin rms / max "
        "| rig twin error rms / max % | |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for contour in CONTOURS:
        for set_id in (1, 2, 3):
            for label in LABELS:
                paper = PAPER_CONTOUR_UM.get((contour, set_id, label))
                r, c = rig.get((set_id, contour, label)), ideal.get((set_id, contour, label))
                if paper is None or r is None or c is None:
                    continue
                err = cell_errors_pct(r, paper)
                cells = [
                    f"{paper[0]:.2f} / {paper[1]:.2f}",
                    f"{r.rms_um:.2f} / {r.max_um:.2f}",
                    f"{c.rms_um:.2f} / {c.max_um:.2f}",
                    f"{signed_pct(err[0], 0, unit='')} / {signed_pct(err[1], 0, unit='')}",
                ]
                role = "fit" if (contour, set_id) in FIT_CELLS else "validation"
                lines.append(f"| {contour} | {set_id} | {label} | " + " | ".join(cells) + f" | {role} |")
    return lines


def acceptance(rig: dict[Key, CaseResult]) -> list[tuple[bool | None, str]]:
    """The acceptance checks on the rig's numbers: (pass, or None for an observation; text)."""
    out: list[tuple[bool | None, str]] = []
    misses, total = [], 0
    for (set_id, contour, label), r in sorted(rig.items()):
        paper = PAPER_CONTOUR_UM.get((contour, set_id, label))
        if paper is None or (contour, set_id) in FIT_CELLS:
            continue
        for kind, e in zip(("rms", "max"), cell_errors_pct(r, paper), strict=True):
            total += 1
            if abs(e) > VALIDATION_PCT:
                misses.append(f"{contour} {set_id} {label} {kind} {signed_pct(e, 0)}")
    if total:
        within = total - len(misses)
        text = f"validation numbers within +-{VALIDATION_PCT:g} % of the paper: {within} of {total}"
        text += f" (target {VALIDATION_TARGET} of {VALIDATION_NUMBERS})" if total == VALIDATION_NUMBERS else ""
        verdict = within >= VALIDATION_TARGET if total == VALIDATION_NUMBERS else None  # judged on the whole matrix
        out.append((verdict, text + (f"; misses: {', '.join(misses)}" if misses else "")))
    for contour in CONTOURS:
        for set_id in (1, 2):
            runs = [rig.get((set_id, contour, x)) for x in LABELS]
            if any(r is None for r in runs):
                continue
            c1, c2, c3 = (r.rms_um for r in runs)
            ratio = c3 / max(c1, c2)
            out.append((ratio >= C3_OVER_C1_C2, f"{contour} Set {set_id}: C3 rms >= 2.5x C1's and C2's (x{ratio:.2f})"))
            out.append(
                (c2 <= C2_OVER_C1 * c1, f"{contour} Set {set_id}: DIARC rms <= 1.05 DARC's ({c2:.2f} vs {c1:.2f} um)")
            )
    for set_id in (1, 2):
        for contour in CONTOURS:
            for label in ("C2r", "C1"):
                r = rig.get((set_id, contour, label))
                if r is None or r.estimates is None:
                    continue
                errs = [error_pct(r.estimates[i], r.true_theta[i]) for i in range(6)]
                text = ", ".join(f"{THETA_NAMES[i]} {signed_pct(e)}" for i, e in enumerate(errs))
                if label == "C2r":
                    dn = [r.estimates[i] - r.true_theta[i] for i in (6, 7)]
                    ok = all(abs(e) <= ESTIMATE_PCT[THETA_NAMES[i].rstrip("12")] for i, e in enumerate(errs))
                    ok = ok and all(abs(d) <= DN_TOL_V for d in dn)
                    text += ", " + ", ".join(
                        f"{THETA_NAMES[i]} {signed_pct(d, 4, unit=' V')}" for i, d in zip((6, 7), dn, strict=True)
                    )
                    out.append((ok, f"DIARC recommended, {contour} Set {set_id}: {text}"))
                else:
                    out.append((None, f"DARC, {contour} Set {set_id} (expected to wander): {text}"))
    return out


def spike_series(overrides: Sequence[str], rig: Sequence[str]) -> dict[tuple[str, str], tuple[np.ndarray, np.ndarray]]:
    """(label, 'rig' | 'ideal') -> (ms from the X reversal, eps_c um): the runs of :func:`spike_run` with
    ``overrides`` and then ``rig`` (the rig twin) or :data:`IDEAL` (the ideal twin)."""
    series = {}
    for label in LABELS:
        for name, plant in (("rig", rig), ("ideal", IDEAL)):
            built, t0 = spike_run(label, (*overrides, *plant))
            trace = execute(built)
            t = trace.t_s[: trace.filled]
            keep = (t >= t0 - SPIKE_HALF_S) & (t <= t0 + SPIKE_HALF_S)
            series[(label, name)] = ((t[keep] - t0) * 1e3, trace.eps_c_m[: trace.filled][keep] * 1e6)
    return series


def spike_run(label: str, overrides: Sequence[str]) -> tuple[BuiltRun, float]:
    """Circle Set 1 with ``label``'s controller, stopped SPIKE_HALF_S after the first reversal of the desired X
    velocity at least SPIKE_HALF_S past the metric window's start (its windows moved inside the shorter run);
    the built run and the reversal's time t0, s."""
    controller, extra, _ = CONTROLLERS[label]
    path = shipped(f"{SET_SCENARIOS[1]}_circle")
    t0 = _first_x_reversal_s(load_scenario(path, (*extra, *overrides), controller), path)
    stop = t0 + SPIKE_HALF_S
    short = (f"duration_s={stop:.6f}", f"window_s=[0, {stop:.6f}]", f"estimates_window_s=[{t0:.6f}, {stop:.6f}]")
    return build(load_scenario(path, (*extra, *overrides, *short), controller), path), t0


def _first_x_reversal_s(scenario: Any, path: Path) -> float:
    """The first sign change of the desired X velocity at least SPIKE_HALF_S after the metric window's start, s."""
    start = scenario.metric_window_s[0] + SPIKE_HALF_S
    built = build(scenario, path)
    t = np.arange(0.0, start + 2.0 * np.pi, 1e-4)
    vx = reference(built.path, built.timing, t).dq_d[:, 0]
    flips = np.nonzero((np.sign(vx[1:]) != np.sign(vx[:-1])) & (t[1:] >= start))[0]
    if flips.size == 0:
        raise RuntimeError(f"{path}: the desired X velocity does not reverse after {start:g} s")
    return float(t[flips[0] + 1])


def spike_figure(series: dict[tuple[str, str], tuple[np.ndarray, np.ndarray]]) -> Any:
    """eps_c around the X reversal, one panel per controller, rig and ideal twin overlaid (matplotlib, Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(LABELS), figsize=(12, 3.4), sharey=True)
    for ax, label in zip(axes, LABELS, strict=True):
        for name in ("rig", "ideal"):
            t_ms, eps_um = series[(label, name)]
            ax.plot(t_ms, eps_um, lw=0.9, label=f"{name} twin")
        # Wrapped: "C2 (DIARC, paper estimator (250/150 Hz filters))" ran into its neighbours' titles.
        ax.set_title(textwrap.fill(f"{label} ({CONTROLLERS[label][2]})", 40), fontsize=10)
        ax.set_xlabel("time from the X reversal [ms]")
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("eps_c [µm]")
    axes[0].legend(fontsize=8)
    fig.suptitle("circle Set 1: contour error around an X reversal")
    fig.tight_layout()
    return fig


def section(
    ideal: Sequence[CaseResult],
    rig: Sequence[CaseResult],
    rig_overrides: Sequence[str],
    out: Path,
    overrides: Sequence[str] = (),
    plant: str = "",
) -> list[str]:
    """The report's rig section (Markdown lines); writes rig.json and the reversal-spike figure into ``out``.

    rig: the rig twin's results (the matrix on the scenarios' plant with ``rig_overrides`` after ``overrides``);
    ideal: the same cases on the ideal twin; plant: the rig twin's plant in words (:func:`plant_label`).
    """
    import matplotlib.pyplot as plt

    rig_by, ideal_by = by_key(rig), by_key(ideal)
    told = " with " + " ".join(f"`{o}`" for o in rig_overrides) if rig_overrides else ""
    lines = [
        "## Paper, rig twin and ideal twin",
        "",
        f"Rig twin: {plant or 'the scenarios’ plant'}{told}. Ideal twin: `{' '.join(IDEAL)}` (the paper's model: "
        "Coulomb friction and viscous damping at the paper's nominal B and Af, no offset, no ripple). "
        "rms / max of eps_c in µm over the same windows as Tables 1-2; circle Set 1 is the calibration's fit, "
        "the other cells validation.",
        "",
        *matrix_table(rig_by, ideal_by),
        "",
        "### Acceptance on the rig twin's numbers",
        "",
    ]
    marks = {True: "PASS: ", False: "FAIL: ", None: ""}
    lines += [f"- {marks[ok]}{text}" for ok, text in acceptance(rig_by)]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cells = [
        {"key": r.case.key, "rig_rms_um": r.rms_um, "rig_max_um": r.max_um, "rig_estimates": r.estimates} for r in rig
    ]
    atomic_write_text(out / RIG_JSON, json.dumps({"overrides": list(rig_overrides), "runs": cells}, indent=2) + "\n")
    fig = spike_figure(spike_series(overrides, rig_overrides))
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI)
    plt.close(fig)
    data = buffer.getvalue()
    atomic_write(out / SPIKE_FILE, lambda fh: fh.write(data))
    caption = "eps_c +-50 ms around an X reversal of circle Set 1, C1-C3, rig twin vs ideal twin"
    lines += ["", f"![{caption}]({SPIKE_FILE})", "", caption, ""]
    return lines


def monitor_alarms(rig: Sequence[str], seconds: float) -> list[str]:
    """The health monitor (DIARC as shipped) on the four no-load / 5 kg paper scenarios with the rig."""
    lines = []
    for set_id in (1, 2):
        for contour in CONTOURS:
            name = f"{SET_SCENARIOS[set_id]}_{contour}"
            extra = [
                *rig,
                "monitor.enable=true",
                f"duration_s={seconds}",
                f"estimates_window_s=[{seconds - 3}, {seconds}]",
            ]
            built = build(load_scenario(shipped(name), extra, "diarc"))
            execute(built)
            alarms = built.monitor.alarms
            lines.append(f"- {name}: {len(alarms)} alarm(s)" + "".join(f"; {a}" for a in alarms[:3]))
    return lines


def plant_label(case: Case) -> str:
    """A case's plant in words, for the report's headings (:attr:`gantry_twin.plant.model.PlantSettings.label`)."""
    return load_scenario(case.scenario_path, case.overrides, case.controller).plant.label


def is_ideal(case: Case) -> bool:
    """Whether a case runs on the ideal twin already (its plant is the paper's model, nothing changed)."""
    plant = load_scenario(case.scenario_path, case.overrides, case.controller).plant
    return plant.label == PlantSettings(model="paper").label
