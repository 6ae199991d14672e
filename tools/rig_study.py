"""The rig plant study: the 32 numbers of Tables 1-2 for a candidate rig plant (docs/rig-plant.md).

    PYTHONPATH=src python tools/rig_study.py eval --set fs_over_fc=2 --set vs_mm_s=10 --set offset_v=0.06 \
        --set ripple_v=0.05 [--jobs 2] [--log runs/rig-study.jsonl] [--sets 1,2,3]
    PYTHONPATH=src python tools/rig_study.py eval --plant rig      # the shipped models/rig.xml as it is
    PYTHONPATH=src python tools/rig_study.py overrides --set ...   # the scenario overrides of a point

Fitting is ``gantry-twin calibrate`` (calibrations/paper_circle_set1.yaml, docs/cli.md); this script only
evaluates a point on the whole of Tables 1-2, on the report's batch runner
(:func:`gantry_twin.reports.paper.run_matrix`, the sweep engine).

A point's parameters, per axis (suffix ``_x`` / ``_y``; without it, both):
``presliding_um`` (Fc / sigma0), ``zeta`` (sigma1 / 2 sqrt(sigma0 M)),
``fs_over_fc``, ``vs_mm_s``, ``offset_v`` (the constant dN), ``half_travel_v``
(its linear part over the half travel), ``ripple_v`` (first harmonic),
``ripple2_v``, ``ripple3_v``, ``phase_rad``; ``af_v``, ``b_v`` (the Af, B that the steady-curve
identification returns; default the paper's 0.1 / 0.15 V and 0.5 / 0.7 V/(m/s)); and ``pitch_mm``
(both axes). Fc and sigma2 follow from that identification constraint in closed form
(:func:`gantry_twin.calibration.lugre_fields`, as ``gantry-twin calibrate`` computes them). The
shipped rig splits the difference between the steady-curve fit and ``gantry-twin identify`` on an
excitation (docs/rig-plant.md): ``--set af_v_x=0.10175 --set af_v_y=0.14891 --set b_v_x=0.49642
--set b_v_y=0.71405``.

Each case is one of the report's (gantry_twin.reports.paper.paper_matrix: Sets 1-3,
C1-C3) shortened to 6.5 s (every contour window ends by then; the loop is
causal), on ``--jobs`` local worker processes. Prints the 32 cells, paper / twin / error,
and the acceptance counts; appends one JSON line per point to ``--log``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from gantry_twin.calibration import lugre_fields
from gantry_twin.plant.model import Plant, moving_masses_kg
from gantry_twin.reports.paper import PAPER_CONTOUR_UM, paper_matrix, run_matrix

AXES = ("x", "y")
LABELS = ("C1", "C2", "C3")
CONTOURS = ("circle", "ellipse")
SHORT = ("duration_s=6.5", "estimates_window_s=[3.5, 6.5]")
#: The paper's nominal Af (V) and B (V/(m/s)) per axis: the identification constraint's defaults.
AF_V = (0.1, 0.15)
B_V_S_M = (0.5, 0.7)
AXIS_DEFAULTS = {
    "presliding_um": 3.0,
    "zeta": 0.05,
    "fs_over_fc": 2.0,
    "vs_mm_s": 10.0,
    "offset_v": 0.06,
    "half_travel_v": 0.0,
    "ripple_v": 0.05,
    "ripple2_v": 0.0,
    "ripple3_v": 0.0,
    "phase_rad": 0.0,
}
DEFAULTS = {
    **{f"{k}_{a}": v for k, v in AXIS_DEFAULTS.items() for a in AXES},
    **{f"af_v_{a}": v for a, v in zip(AXES, AF_V, strict=True)},
    **{f"b_v_{a}": v for a, v in zip(AXES, B_V_S_M, strict=True)},
    "pitch_mm": 16.0,
    "phase_rad_y": 1.0,
}


def full_point(given: dict[str, float]) -> dict[str, float]:
    point = dict(DEFAULTS)
    for name, value in given.items():
        if name in AXIS_DEFAULTS:
            point.update({f"{name}_{a}": float(value) for a in AXES})
        elif name in point:
            point[name] = float(value)
        else:
            raise SystemExit(f"unknown parameter {name!r}")
    return point


def lugre_axis(point: dict[str, float], axis: str) -> dict[str, float]:
    """One axis' LuGre parameters (SI) of a point, Fc and sigma2 by the identification constraint."""
    i = AXES.index(axis)
    plant = Plant()
    shape = {
        "fs_over_fc": min(point[f"fs_over_fc_{axis}"], 2.0 - 1e-9),
        "vs_m_s": point[f"vs_mm_s_{axis}"] * 1e-3,
        "presliding_m": point[f"presliding_um_{axis}"] * 1e-6,
        "zeta": point[f"zeta_{axis}"],
    }
    mass = float(moving_masses_kg(plant.model, plant.dof_index)[i])
    return lugre_fields(shape, point[f"af_v_{axis}"], point[f"b_v_{axis}"], mass, float(plant.gear_n_per_v[i]))


def overrides(point: dict[str, float]) -> list[str]:
    """The scenario overrides of a point: plant.friction (LuGre), plant.offset, plant.ripple on the paper's file."""
    out = ["plant.friction.model=lugre"]
    for axis in AXES:
        out += [f"plant.friction.{axis}.{k}={v:.12g}" for k, v in lugre_axis(point, axis).items()]
        out.append(f"plant.offset.{axis}.constant_v={point[f'offset_v_{axis}']:.6g}")
        if point[f"half_travel_v_{axis}"]:
            out.append(f"plant.offset.{axis}.half_travel_v={point[f'half_travel_v_{axis}']:.6g}")
        out.append(f"plant.ripple.{axis}.pitch_m={point['pitch_mm'] * 1e-3:.6g}")
        harmonics = [point[f"ripple_v_{axis}"], point[f"ripple2_v_{axis}"], point[f"ripple3_v_{axis}"]]
        while harmonics and harmonics[-1] == 0.0:
            harmonics.pop()
        phase = point[f"phase_rad_{axis}"]
        listed = ", ".join(f"{{amplitude_v: {h:.6g}, phase_rad: {phase:.6g}}}" for h in harmonics)
        out.append(f"plant.ripple.{axis}.harmonics=[{listed}]")
    return out


def cells(sets: tuple[int, ...]) -> list[tuple[str, int, str]]:
    return [
        (c, s, label)
        for s in sets
        for c in ("circle", "ellipse")
        for label in LABELS
        if (c, s, label) in PAPER_CONTOUR_UM
    ]


def evaluate(
    plant_overrides: list[str], sets: tuple[int, ...], jobs: int, contours: tuple[str, ...] = CONTOURS
) -> dict[tuple[str, int, str], tuple]:
    """The cells of ``sets``: the report's cases with the point's overrides, on the report's batch runner."""
    cases = paper_matrix((*SHORT, *plant_overrides), sets=sets, contours=contours, labels=LABELS)
    return {(r.case.contour, r.case.set_id, r.case.label): (r.rms_um, r.max_um) for r in run_matrix(cases, jobs)}


def judge(numbers: dict) -> list[str]:
    """The acceptance lines of docs/rig-plant.md on the numbers that were run."""
    lines = []
    fit = [(k, i) for k in numbers if k[:2] == ("circle", 1) for i in (0, 1)]
    held = [(k, i) for k in numbers if k[:2] != ("circle", 1) for i in (0, 1)]

    def err(k, i):  # noqa: ANN001, ANN202
        return numbers[k][i] / PAPER_CONTOUR_UM[k][i] - 1.0

    ok = sum(abs(err(k, i)) <= 0.15 for k, i in fit)
    lines.append(f"fit: {ok} of {len(fit)} circle Set 1 numbers within 15 %")
    ok = sum(abs(err(k, i)) <= 0.30 for k, i in held)
    misses = [f"{k[0]} {k[1]} {k[2]} {'rms' if i == 0 else 'max'} {100 * err(k, i):+.0f} %" for k, i in held]
    misses = [m for (k, i), m in zip(held, misses, strict=True) if abs(err(k, i)) > 0.30]
    lines.append(f"validation: {ok} of {len(held)} within 30 %; misses: {', '.join(misses) or 'none'}")
    for contour in ("circle", "ellipse"):
        for s in (1, 2):
            got = [numbers.get((contour, s, label)) for label in LABELS]
            if None in got:
                continue
            c1, c2, c3 = (g[0] for g in got)
            lines.append(
                f"{contour} Set {s}: C3 / max(C1, C2) rms {c3 / max(c1, c2):.2f} (>= 2.5), C2 / C1 rms {c2 / c1:.3f} "
                "(<= 1.05)"
            )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mode", choices=("eval", "overrides"))
    parser.add_argument("--set", action="append", default=[], metavar="NAME=V")
    parser.add_argument("--plant", choices=("point", "rig", "paper"), default="point")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--sets", default="1,2,3")
    parser.add_argument("--log", type=Path, default=Path("runs/rig-study.jsonl"))
    args = parser.parse_args()
    given = {k.strip(): float(v) for k, _, v in (p.partition("=") for p in args.set)}
    point = full_point(given)
    plant_overrides = overrides(point) if args.plant == "point" else [f"plant.model={args.plant}"]
    if args.mode == "overrides":
        print("\n".join(plant_overrides))
        return
    sets = tuple(int(s) for s in args.sets.split(","))
    started = time.perf_counter()
    numbers = evaluate(plant_overrides, sets, args.jobs)
    print(f"| contour | set | ctrl | paper rms / max | twin rms / max | error rms / max % |  ({args.plant})")
    for key in cells(sets):
        p, t = PAPER_CONTOUR_UM[key], numbers[key]
        e = [100 * (t[i] / p[i] - 1.0) for i in (0, 1)]
        print(
            f"| {key[0]} | {key[1]} | {key[2]} | {p[0]:.2f} / {p[1]:.2f} | {t[0]:.2f} / {t[1]:.2f} | "
            f"{e[0]:+.0f} / {e[1]:+.0f} |"
        )
    lines = judge(numbers)
    print("\n".join(lines))
    print(f"({time.perf_counter() - started:.0f} s)")
    args.log.parent.mkdir(parents=True, exist_ok=True)
    entry = {
        "plant": args.plant,
        "point": point if args.plant == "point" else None,
        "overrides": plant_overrides,
        "numbers_um": {f"{k[0]} {k[1]} {k[2]}": list(v) for k, v in numbers.items()},
        "judged": lines,
    }
    with args.log.open("a") as handle:
        handle.write(json.dumps(entry) + "\n")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
