"""Calibrate the rig's friction (and force ripple) on circle Set 1 of Table 1 only (docs/friction.md).

    PYTHONPATH=src python tools/calibrate_friction.py map --grid fs_over_fc=1,1.5,2 --grid vs_mm_s=1,10,40 \
        [--set zeta=0.3] --out runs/friction-map [--workers 2]
    PYTHONPATH=src python tools/calibrate_friction.py fit [--start-map runs/friction-map/map.jsonl --starts 3] \
        [--free fs_over_fc_x,fs_over_fc_y,vs_mm_s_x,vs_mm_s_y] --out runs/calibration [--workers 2] [--evaluations 80]

One command each, reproducible (every run is deterministic; the grid and
Nelder-Mead are deterministic). The parameters, per axis (suffix ``_x`` /
``_y``; a name without the suffix sets both axes):

- ``presliding_um``: the pre-sliding distance Fc / sigma0, um (sigma0 follows
  from the axis' Fc);
- ``zeta``: sigma1 as a fraction of the axis' critical bristle damping
  2 sqrt(sigma0 M) (M the axis' moving mass);
- ``fs_over_fc``: Fs / Fc; ``vs_mm_s``: the Stribeck velocity, mm/s,

with Fc and sigma2 the paper's Af kf and B kf (the model's frictionloss and
damping) as the calibration requires, unless ``fc_scale`` (Fc / (Af kf), default 1;
outside the calibration's constraint, docs/friction.md) is set, and ``ripple_v``:
the amplitude (V) of a force ripple, the twin's cogging change at 16 mm pitch
on both axes (Y phase 1 rad).

Each point is judged on the six numbers of circle Set 1 (C1 DARC, C2 DIARC
with the paper's estimator, C3 DRC: rms and max of eps_c over [T, 2T], um) by
the mean squared log ratio twin / paper. The runs are the report's cases
(gantry_twin.reports.paper) on the sweep engine's Dask cluster, shortened to 6.5 s
(the window ends at 2 pi s; the loop is causal, so the numbers are those of
the 30 s runs). Every other cell of Tables 1-2 is validation and is never run
here.

``map`` runs every point of the grid (the product of the ``--grid`` values,
the rest at ``--set`` or the defaults; points with Fs = Fc keep one vs, which
then has no effect) and appends one JSON line per point to ``map.jsonl``.
``fit`` runs Nelder-Mead in the unit box of the ``--free`` parameters from
the default point, or from each of the ``--starts`` best points of a map,
and writes ``fit.json`` (the parameters, the scenario overrides that make the
rig plant, the six numbers, residuals, every evaluation) and ``fit.md``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from gantry_twin.plant import Plant
from gantry_twin.reports.paper import PAPER_CONTOUR_UM, Case, _load, _warm_run_case, paper_matrix
from gantry_twin.sweep.engine import open_client, prepare_workers, run_tasks

LABELS = ("C1", "C2", "C3")
AXES = ("x", "y")
#: Per-axis parameters: name -> (low, high, log scale, default); the box is the physical range (docs/friction.md).
AXIS_BOX = {
    "presliding_um": (0.1, 50.0, True, 10.0),
    "zeta": (0.0, 0.99, False, 0.05),
    "fs_over_fc": (1.0, 2.0, False, 1.3),
    "vs_mm_s": (0.1, 50.0, True, 5.0),
    "fc_scale": (1.0, 3.0, False, 1.0),
}
RIPPLE_BOX = (0.0, 0.15, False, 0.0)
RIPPLE_PITCH_M = 0.016
RIPPLE_PHASE_Y_RAD = 1.0
SHORT = ("duration_s=6.5", "estimates_window_s=[3.5, 6.5]")
PAPER = np.array([v for label in LABELS for v in PAPER_CONTOUR_UM[("circle", 1, label)]])
CELLS = [f"{label} {kind}" for label in LABELS for kind in ("rms", "max")]


def box(name: str) -> tuple[float, float, bool, float]:
    return RIPPLE_BOX if name == "ripple_v" else AXIS_BOX[name.rsplit("_", 1)[0]]


def full_point(given: dict[str, float]) -> dict[str, float]:
    """Every per-axis parameter and the ripple: ``given`` (a name without _x/_y sets both axes), else defaults."""
    point = {f"{name}_{axis}": spec[3] for name, spec in AXIS_BOX.items() for axis in AXES}
    point["ripple_v"] = RIPPLE_BOX[3]
    for name, value in given.items():
        if name in AXIS_BOX:
            point.update({f"{name}_{axis}": float(value) for axis in AXES})
        elif name in point:
            point[name] = float(value)
        else:
            raise SystemExit(f"unknown parameter {name!r}: one of {sorted(point)} or {sorted(AXIS_BOX)}")
    return point


def overrides(point: dict[str, float]) -> list[str]:
    """The scenario overrides that give a plant these parameters (:func:`full_point`'s names)."""
    plant = Plant()
    theta, gear = plant.true_parameters(), plant.gear_n_per_v
    out = ["plant.friction.model=lugre"]
    for i, axis in enumerate(AXES):
        fc = theta[4 + i] * gear[i] * point[f"fc_scale_{axis}"]
        sigma0 = fc / (point[f"presliding_um_{axis}"] * 1e-6)
        sigma1 = point[f"zeta_{axis}"] * 2.0 * math.sqrt(sigma0 * theta[i] * gear[i])
        if point[f"fc_scale_{axis}"] != 1.0:
            out.append(f"plant.friction.{axis}.fc_n={fc:.6g}")
        out += [
            f"plant.friction.{axis}.sigma0_n_m={sigma0:.6g}",
            f"plant.friction.{axis}.sigma1_ns_m={sigma1:.6g}",
            f"plant.friction.{axis}.fs_n={point[f'fs_over_fc_{axis}'] * fc:.6g}",
            f"plant.friction.{axis}.vs_m_s={point[f'vs_mm_s_{axis}'] * 1e-3:.6g}",
        ]
    a = point["ripple_v"]
    if a > 0.0:
        out.append(
            f"changes.cogging=[{{axis: x, amplitude_v: {a:.6g}, pitch_m: {RIPPLE_PITCH_M}}}, "
            f"{{axis: y, amplitude_v: {a:.6g}, pitch_m: {RIPPLE_PITCH_M}, phase_rad: {RIPPLE_PHASE_Y_RAD}}}]"
        )
    return out


def cost(numbers: np.ndarray) -> float:
    """The mean squared log ratio twin / paper of the six numbers."""
    return float(np.mean(np.log(numbers / PAPER) ** 2))


def point_cases(point: dict[str, float]) -> list[Case]:
    return paper_matrix((*SHORT, *overrides(point)), sets=(1,), contours=("circle",), labels=LABELS)


class Evaluator:
    """Runs points (three cases each) on the sweep engine's cluster; every point is logged to ``log``."""

    def __init__(self, client, log: Path) -> None:
        self.client, self.log, self.history = client, log, []
        first = point_cases(full_point({}))
        prepare_workers(client, [_load(c).resolved() for c in first], first[0].scenario_path)

    def run(self, points: Sequence[dict[str, float]]) -> list[np.ndarray]:
        """The six numbers of each point (all points' cases queued at once: both workers stay busy)."""
        cases = [c for p in points for c in point_cases(p)]
        got: dict[int, tuple[float, float]] = {}
        started = time.perf_counter()
        for index, result, error in run_tasks(self.client, _warm_run_case, [(c,) for c in cases], False, "cal"):
            if error is not None:
                raise error
            got[index] = (result.rms_um, result.max_um)
            p, k = divmod(index, len(LABELS))
            if all(p * len(LABELS) + j in got for j in range(len(LABELS))):
                numbers = np.array([v for j in range(len(LABELS)) for v in got[p * len(LABELS) + j]])
                self._record(points[p], numbers, time.perf_counter() - started)
        return [np.array([v for j in range(len(LABELS)) for v in got[p * len(LABELS) + j]]) for p in range(len(points))]

    def _record(self, point: dict[str, float], numbers: np.ndarray, elapsed_s: float) -> None:
        entry = {"point": point, "numbers_um": numbers.tolist(), "cost": cost(numbers)}
        self.history.append(entry)
        with self.log.open("a") as handle:
            handle.write(json.dumps(entry) + "\n")
        shown = " ".join(f"{k}={v:.3g}" for k, v in point.items())
        print(
            f"{len(self.history):4d} cost {entry['cost']:.4f} | {' '.join(f'{x:.2f}' for x in numbers)} "
            f"| C3/C1 {numbers[4] / numbers[0]:.2f} | {shown} ({elapsed_s:.0f} s)",
            flush=True,
        )


def grid_points(grid: dict[str, list[float]], base: dict[str, float]) -> list[dict[str, float]]:
    """The product of the grid's values over ``base``; with Fs = Fc on an axis, one vs of that axis kept."""
    names = list(grid)
    points, seen = [], set()
    for values in itertools.product(*(grid[n] for n in names)):
        point = full_point({**base, **dict(zip(names, values, strict=True))})
        for axis in AXES:
            if point[f"fs_over_fc_{axis}"] == 1.0:
                point[f"vs_mm_s_{axis}"] = AXIS_BOX["vs_mm_s"][3]
        key = tuple(sorted(point.items()))
        if key not in seen:
            seen.add(key)
            points.append(point)
    return points


def to_unit(point: dict[str, float], free: Sequence[str]) -> np.ndarray:
    out = []
    for name in free:
        lo, hi, log, _ = box(name)
        x = point[name]
        out.append(math.log(x / lo) / math.log(hi / lo) if log else (x - lo) / (hi - lo))
    return np.array(out)


def from_unit(u: np.ndarray, free: Sequence[str], base: dict[str, float]) -> dict[str, float]:
    point = dict(base)
    for name, x in zip(free, np.clip(u, 0.0, 1.0), strict=True):
        lo, hi, log, _ = box(name)
        point[name] = lo * (hi / lo) ** x if log else lo + (hi - lo) * x
    return point


def _parse_pairs(pairs: Sequence[str], many: bool) -> dict:
    out = {}
    for pair in pairs:
        name, _, values = pair.partition("=")
        numbers = [float(v) for v in values.split(",")]
        out[name.strip()] = numbers if many else numbers[0]
    return out


def write_fit(out: Path, history: list[dict], messages: list[str]) -> None:
    best = min(history, key=lambda h: h["cost"])
    numbers = np.array(best["numbers_um"])
    residual_pct = (numbers / PAPER - 1.0) * 100.0
    fit = {
        "parameters": best["point"],
        "overrides": overrides(best["point"]),
        "cost": best["cost"],
        "cells": {
            n: {"paper_um": p, "twin_um": t, "residual_pct": r}
            for n, p, t, r in zip(CELLS, PAPER, numbers, residual_pct, strict=True)
        },
        "evaluations": len(history),
        "optimizer": messages,
        "history": history,
    }
    (out / "fit.json").write_text(json.dumps(fit, indent=2))
    lines = ["# Friction calibration: circle Set 1 (tools/calibrate_friction.py)", ""]
    lines += [f"- {k} = {v:.4g}" for k, v in best["point"].items()]
    lines += ["", "| cell | paper um | twin um | residual % |", "|---|---|---|---|"]
    lines += [
        f"| {n} | {p:.2f} | {t:.2f} | {r:+.1f} |"
        for n, p, t, r in zip(CELLS, PAPER, numbers, residual_pct, strict=True)
    ]
    (out / "fit.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def map_figure(maps: Sequence[Path], path: Path) -> None:
    """C3's rms against C1's rms, and against C1's max, of every point of the maps; the paper's cell and +-15 %."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 4.4))
    pairs = ((0, 4, "C1 DARC rms"), (1, 4, "C1 DARC max"), (2, 4, "C2 DIARC rms"))
    for m in maps:
        numbers = np.array([json.loads(line)["numbers_um"] for line in m.read_text().splitlines() if line.strip()])
        for ax, (i, j, _) in zip(axes, pairs, strict=True):
            ax.scatter(numbers[:, i], numbers[:, j], s=9, alpha=0.7, label=f"{m.parent.name} ({len(numbers)})")
    for ax, (i, j, name) in zip(axes, pairs, strict=True):
        ax.add_patch(
            plt.Rectangle(
                (0.85 * PAPER[i], 0.85 * PAPER[j]), 0.3 * PAPER[i], 0.3 * PAPER[j], fill=False, ec="k", lw=1.0
            )
        )
        ax.plot(PAPER[i], PAPER[j], "k*", ms=11, label="paper (+-15 % box)")
        ax.set_xlabel(f"{name} [um]")
        ax.set_ylabel("C3 DRC rms [um]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle("circle Set 1 on the friction map (tools/calibrate_friction.py map)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    print(f"wrote {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mode", choices=("map", "fit", "figure"))
    parser.add_argument("maps", nargs="*", type=Path, help="figure: map.jsonl files (each one colour)")
    parser.add_argument("--out", type=Path, default=Path("runs/calibration"))
    parser.add_argument("--workers", "--jobs", type=int, default=2)
    parser.add_argument("--grid", action="append", default=[], metavar="NAME=V1,V2,...")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=V", help="a fixed parameter")
    parser.add_argument(
        "--free",
        default="presliding_um_x,presliding_um_y,zeta_x,zeta_y,fs_over_fc_x,fs_over_fc_y,vs_mm_s_x,vs_mm_s_y,ripple_v",
    )
    parser.add_argument("--start-map", type=Path, help="a map.jsonl: start from its best points")
    parser.add_argument("--starts", type=int, default=1)
    parser.add_argument("--evaluations", type=int, default=80, help="per start")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    base = _parse_pairs(args.set, many=False)
    if args.mode == "figure":
        map_figure(args.maps, args.out / "friction_map.png")
        return

    with open_client(workers=args.workers) as client:
        if args.mode == "map":
            evaluator = Evaluator(client, args.out / "map.jsonl")
            points = grid_points(_parse_pairs(args.grid, many=True), base)
            print(f"{len(points)} points, {len(points) * len(LABELS)} runs", flush=True)
            evaluator.run(points)
            return
        evaluator = Evaluator(client, args.out / "evaluations.jsonl")
        free = [n for n in args.free.split(",") if n]
        if args.start_map:
            entries = [json.loads(line) for line in args.start_map.read_text().splitlines() if line.strip()]
            starts = [e["point"] for e in sorted(entries, key=lambda e: e["cost"])[: args.starts]]
        else:
            starts = [full_point(base)]
        messages = []
        for start in starts:
            start = full_point({**start, **base})

            def objective(u: np.ndarray, start: dict[str, float] = start) -> float:
                return cost(evaluator.run([from_unit(u, free, start)])[0])

            result = minimize(
                objective,
                to_unit(start, free),
                method="Nelder-Mead",
                options={"maxfev": args.evaluations, "xatol": 0.01, "fatol": 1e-4},
            )
            messages.append(f"{result.message} ({result.nfev} evaluations)")
    write_fit(args.out, evaluator.history, messages)


if __name__ == "__main__":
    main()
