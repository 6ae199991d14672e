"""The paper's matrix with the rig's friction beside the Coulomb twin, cell by cell (issue 15, item 6).

    PYTHONPATH=src python tools/friction_report.py FIT_JSON [--out runs/friction-report] [--jobs 2] [--monitor-s 60]

FIT_JSON: the ``fit.json`` of tools/calibrate_friction.py (its ``overrides``
make the rig plant). Runs the report's matrix (gantry_twin.report, the sweep
engine's cluster) twice, rig and Coulomb, and writes ``friction.md``:
paper / twin rig / twin Coulomb for every cell of Tables 1-2 with the rig's
error per cell (circle Set 1 is the fit, the other 26 numbers validation),
the issue's acceptance checks (validation within +-30 %, C3 >= 2.5x C1 and
C2, DIARC rms <= 1.05 DARC's, DIARC recommended estimates against the true
theta of the rig plant, DARC's estimates), the health monitor on the four
no-load / 5 kg paper scenarios over ``--monitor-s`` seconds, and a figure of
eps_c +-50 ms around an X reversal on circle Set 1 for C1-C3, rig and Coulomb.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from gantry_twin.metrics import error_pct
from gantry_twin.plant import THETA_NAMES
from gantry_twin.report import CONTOURS, PAPER_CONTOUR_UM, SET_SCENARIOS, paper_matrix, run_matrix
from gantry_twin.run import execute
from gantry_twin.scenario import build, load_scenario, shipped

LABELS = ("C1", "C2", "C3")
NAMES = {"C1": "darc", "C2": "diarc", "C3": "drc"}
FIT_CELLS = {("circle", 1)}


def _by_key(results: list) -> dict:
    return {(r.case.set_id, r.case.contour, r.case.label): r for r in results}


def spike_figure(overrides: list[str], out: Path) -> str:
    """eps_c +-50 ms around the X reversal nearest 1.5 pi s on circle Set 1, C1-C3, rig vs Coulomb."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.4), sharey=True)
    for ax, label in zip(axes, LABELS, strict=True):
        for name, extra in (("rig", overrides), ("coulomb", [])):
            built = build(
                load_scenario(
                    shipped("no_load_circle"),
                    [*extra, "duration_s=5", "window_s=[0, 5]", "estimates_window_s=[4, 5]"],
                    NAMES[label],
                )
            )
            trace = execute(built)
            t, vx = trace.t_s, np.gradient(trace.q_m[:, 0], trace.t_s)
            flips = np.nonzero((np.sign(vx[1:]) != np.sign(vx[:-1])) & (t[1:] > 3.5) & (t[1:] < 4.8))[0]
            t0 = t[flips[0] + 1] if flips.size else 1.5 * np.pi
            w = (t >= t0 - 0.05) & (t <= t0 + 0.05)
            ax.plot((t[w] - t0) * 1e3, trace.eps_c_m[w] * 1e6, label=name)
        ax.set_title(f"{label} ({NAMES[label].upper()})")
        ax.set_xlabel("time from X reversal (ms)")
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("eps_c (um)")
    axes[0].legend()
    fig.tight_layout()
    path = out / "reversal_spike.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path.name


def monitor_alarms(overrides: list[str], seconds: float) -> list[str]:
    lines = []
    for set_id in (1, 2):
        for contour in CONTOURS:
            name = f"{SET_SCENARIOS[set_id]}_{contour}"
            extra = [
                *overrides,
                "monitor.enable=true",
                f"duration_s={seconds}",
                f"estimates_window_s=[{seconds - 3}, {seconds}]",
            ]
            built = build(load_scenario(shipped(name), extra, "diarc"))
            execute(built)
            alarms = built.monitor.alarms
            lines.append(f"- {name}: {len(alarms)} alarm(s)" + "".join(f"; {a}" for a in alarms[:3]))
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("fit", type=Path)
    parser.add_argument("--out", type=Path, default=Path("runs/friction-report"))
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--monitor-s", type=float, default=60.0)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    overrides = list(json.loads(args.fit.read_text())["overrides"])
    rig = _by_key(run_matrix(paper_matrix(overrides), jobs=args.jobs))
    coulomb = _by_key(run_matrix(paper_matrix(()), jobs=args.jobs))

    lines = ["# The rig's friction vs the Coulomb twin (tools/friction_report.py)", ""]
    lines += ["Rig plant: " + " ".join(f"`{o}`" for o in overrides), ""]
    lines += [
        "| contour | set | ctrl | paper rms / max | rig rms / max | Coulomb rms / max | rig error rms / max % | |"
    ]
    lines += ["|---|---|---|---|---|---|---|---|"]
    within, total = 0, 0
    for contour in CONTOURS:
        for set_id in (1, 2, 3):
            for label in LABELS:
                paper = PAPER_CONTOUR_UM.get((contour, set_id, label))
                if paper is None:
                    continue
                r, c = rig[(set_id, contour, label)], coulomb[(set_id, contour, label)]
                err = [(r.rms_um / paper[0] - 1) * 100, (r.max_um / paper[1] - 1) * 100]
                fit = (contour, set_id) in FIT_CELLS
                if not fit:
                    total += 2
                    within += sum(abs(e) <= 30.0 for e in err)
                role = "fit" if fit else "validation"
                cells = [
                    f"{paper[0]:.2f} / {paper[1]:.2f}",
                    f"{r.rms_um:.2f} / {r.max_um:.2f}",
                    f"{c.rms_um:.2f} / {c.max_um:.2f}",
                    f"{err[0]:+.0f} / {err[1]:+.0f}",
                ]
                lines.append(f"| {contour} | {set_id} | {label} | " + " | ".join(cells) + f" | {role} |")
    lines += ["", "## Acceptance (issue 15)", ""]
    lines.append(f"- validation numbers within +-30 % of the paper: {within} of {total} (target 20)")
    for contour in CONTOURS:
        for set_id in (1, 2):
            c1, c2, c3 = (rig[(set_id, contour, x)].rms_um for x in LABELS)
            ok3 = c3 >= 2.5 * max(c1, c2)
            ok2 = c2 <= 1.05 * c1
            lines.append(
                f"- {contour} Set {set_id}: C3 >= 2.5x C1, C2: {'pass' if ok3 else 'FAIL'} (x{c3 / max(c1, c2):.2f}); "
                f"DIARC rms <= 1.05 DARC's: {'pass' if ok2 else 'FAIL'} ({c2:.2f} vs {c1:.2f} um)"
            )
    limits = {"M": 3.0, "B": 10.0, "Af": 10.0}
    for set_id in (1, 2):
        for contour in CONTOURS:
            for label in ("C2r", "C1"):
                r = rig.get((set_id, contour, label))
                if r is None or r.estimates is None:
                    continue
                errs = [error_pct(r.estimates[i], r.true_theta[i]) for i in range(6)]
                text = ", ".join(f"{THETA_NAMES[i]} {e:+.1f} %" for i, e in enumerate(errs))
                if label == "C2r":
                    ok = all(abs(e) <= limits[THETA_NAMES[i].rstrip("12")] for i, e in enumerate(errs))
                    lines.append(f"- DIARC recommended, {contour} Set {set_id}: {'pass' if ok else 'FAIL'} ({text})")
                else:
                    lines.append(f"- DARC, {contour} Set {set_id} (expected to wander): {text}")
    lines += ["", f"## Health monitor, rig friction, {args.monitor_s:g} s, DIARC", ""]
    lines += monitor_alarms(overrides, args.monitor_s)
    lines += ["", f"![reversal spike]({spike_figure(overrides, args.out)})", ""]
    (args.out / "friction.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
