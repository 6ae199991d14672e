"""Calibrate the rig's friction (and force ripple) on circle Set 1 of Table 1 only (issue 15, item 5).

    PYTHONPATH=src python tools/calibrate_friction.py [--out runs/calibration] [--jobs 2] [--evaluations 60]

One command, reproducible (a fixed start and a deterministic Nelder-Mead
search; every run is deterministic). Fits, shared by both axes:

- sigma0 (N/m), sigma1 as a fraction zeta of the X bristle's critical damping
  2 sqrt(sigma0 M1), Fs / Fc and vs (m/s) of the LuGre friction (Fc and sigma2
  stay the paper's Af kf and B kf: the model's frictionloss and damping);
- the amplitude (V) of a force ripple, the twin's cogging change at 16 mm
  pitch on both axes (Y phase 1 rad): the smallest extra rig property that
  docs/friction.md found the rms needs,

to the six numbers of circle Set 1 (C1 DARC, C2 DIARC with the paper's
estimator, C3 DRC: rms and max of eps_c over [T, 2T], um), minimising the
mean squared log ratio twin / paper. The runs are the report's cases
(gantry_twin.report) on the sweep engine's Dask cluster, shortened to 6.5 s
(the window ends at 2 pi s). Every other cell of Tables 1-2 is validation and
is never run here.

Writes ``fit.json`` (the parameters in SI and as scenario overrides, the six
numbers, residuals, every evaluation) and ``fit.md`` into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from gantry_twin.plant import Plant
from gantry_twin.report import PAPER_CONTOUR_UM, Case, _load, _warm_run_case, paper_matrix
from gantry_twin.sweep.engine import open_client, prepare_workers, run_tasks

LABELS = ("C1", "C2", "C3")
#: Search box per parameter (name, low, high, log scale), and the start (a plausible rig).
BOX = (
    ("sigma0_n_m", 1.0e5, 1.0e7, True),
    ("zeta", 0.005, 0.5, True),
    ("fs_over_fc", 1.0, 2.0, False),
    ("vs_m_s", 5.0e-4, 0.03, True),
    ("ripple_v", 0.0, 0.15, False),
)
START = {"sigma0_n_m": 1.0e6, "zeta": 0.05, "fs_over_fc": 1.3, "vs_m_s": 0.005, "ripple_v": 0.05}
RIPPLE_PITCH_M = 0.016
RIPPLE_PHASE_Y_RAD = 1.0
SHORT = ("duration_s=6.5", "estimates_window_s=[3.5, 6.5]")


def to_unit(params: dict[str, float]) -> np.ndarray:
    out = []
    for name, lo, hi, log in BOX:
        x = params[name]
        out.append((math.log(x / lo) / math.log(hi / lo)) if log else (x - lo) / (hi - lo))
    return np.array(out)


def from_unit(u: np.ndarray) -> dict[str, float]:
    u = np.clip(u, 0.0, 1.0)
    out = {}
    for (name, lo, hi, log), x in zip(BOX, u, strict=True):
        out[name] = lo * (hi / lo) ** x if log else lo + (hi - lo) * x
    return out


def overrides(params: dict[str, float]) -> list[str]:
    """The scenario overrides that give a plant these parameters."""
    mass_x = Plant().true_parameters()[0] * Plant().gear_n_per_v[0]
    sigma1 = params["zeta"] * 2.0 * math.sqrt(params["sigma0_n_m"] * mass_x)
    theta = Plant().true_parameters()
    gear = Plant().gear_n_per_v
    out = ["plant.friction.model=lugre"]
    for i, axis in enumerate(("x", "y")):
        fc = theta[4 + i] * gear[i]
        out += [
            f"plant.friction.{axis}.sigma0_n_m={params['sigma0_n_m']:.6g}",
            f"plant.friction.{axis}.sigma1_ns_m={sigma1:.6g}",
            f"plant.friction.{axis}.fs_n={params['fs_over_fc'] * fc:.6g}",
            f"plant.friction.{axis}.vs_m_s={params['vs_m_s']:.6g}",
        ]
    a = params["ripple_v"]
    if a > 0.0:
        out.append(
            f"changes.cogging=[{{axis: x, amplitude_v: {a:.6g}, pitch_m: {RIPPLE_PITCH_M}}}, "
            f"{{axis: y, amplitude_v: {a:.6g}, pitch_m: {RIPPLE_PITCH_M}, phase_rad: {RIPPLE_PHASE_Y_RAD}}}]"
        )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("runs/calibration"))
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--evaluations", type=int, default=60)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    paper = np.array([v for label in LABELS for v in PAPER_CONTOUR_UM[("circle", 1, label)]])
    history: list[dict] = []

    with open_client(workers=args.jobs) as client:
        first = paper_matrix((*SHORT, *overrides(START)), sets=(1,), contours=("circle",), labels=LABELS)
        prepare_workers(client, [_load(c).resolved() for c in first], first[0].scenario_path)

        def twin(params: dict[str, float]) -> np.ndarray:
            cases: list[Case] = paper_matrix(
                (*SHORT, *overrides(params)), sets=(1,), contours=("circle",), labels=LABELS
            )
            got: dict[int, tuple[float, float]] = {}
            for index, result, error in run_tasks(client, _warm_run_case, [(c,) for c in cases], False, "fit"):
                if error is not None:
                    raise error
                got[index] = (result.rms_um, result.max_um)
            return np.array([v for i in range(len(cases)) for v in got[i]])

        def cost(u: np.ndarray) -> float:
            params = from_unit(u)
            started = time.perf_counter()
            numbers = twin(params)
            value = float(np.mean(np.log(numbers / paper) ** 2))
            history.append({"params": params, "numbers_um": numbers.tolist(), "cost": value})
            print(
                f"{len(history):3d} cost {value:.4f} "
                + " ".join(f"{k}={v:.4g}" for k, v in params.items())
                + " | "
                + " ".join(f"{x:.2f}" for x in numbers)
                + f" ({time.perf_counter() - started:.0f} s)",
                flush=True,
            )
            return value

        result = minimize(
            cost,
            to_unit(START),
            method="Nelder-Mead",
            options={"maxfev": args.evaluations, "initial_simplex": None, "xatol": 0.01, "fatol": 1e-4},
        )
    best = min(history, key=lambda h: h["cost"])
    numbers = np.array(best["numbers_um"])
    residual_pct = (numbers / paper - 1.0) * 100.0
    names = [f"{label} {kind}" for label in LABELS for kind in ("rms", "max")]
    fit = {
        "parameters": best["params"],
        "overrides": overrides(best["params"]),
        "cost": best["cost"],
        "cells": {
            n: {"paper_um": p, "twin_um": t, "residual_pct": r}
            for n, p, t, r in zip(names, paper, numbers, residual_pct, strict=True)
        },
        "evaluations": len(history),
        "optimizer": {"message": str(result.message), "nfev": int(result.nfev)},
        "history": history,
    }
    (args.out / "fit.json").write_text(json.dumps(fit, indent=2))
    lines = ["# Friction calibration: circle Set 1 (tools/calibrate_friction.py)", ""]
    lines += [f"- {k} = {v:.4g}" for k, v in best["params"].items()]
    lines += ["", "| cell | paper um | twin um | residual % |", "|---|---|---|---|"]
    lines += [
        f"| {n} | {p:.2f} | {t:.2f} | {r:+.1f} |"
        for n, p, t, r in zip(names, paper, numbers, residual_pct, strict=True)
    ]
    (args.out / "fit.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
