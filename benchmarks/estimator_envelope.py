"""DIARC's estimate errors over the machine's envelope (docs/estimator-envelope.md): write the sweep, read its results.

    PYTHONPATH=src python benchmarks/estimator_envelope.py write [--monitor [--corners]] [--earlier-estimator] \
        [--estimator paper|recommended] [--keep-runs]
    gantry-twin sweep estimator_envelope --workers 2
    PYTHONPATH=src python benchmarks/estimator_envelope.py map runs/sweeps/estimator_envelope/results.parquet... \
        [--figure docs/images/estimator_envelope.png] [--rejudge]

``write`` (re)writes sweeps/estimator_envelope.yaml: the grid of peak
speeds SPEEDS_M_S and sizes SIZES_M (circle radius; ellipse semi-axes r and
r / 2, the paper's shape), the rates rate = speed / size within the
scenario's 20 rad/s, both payloads and the estimators of ESTIMATORS. With
``--earlier-estimator`` the estimator axis also holds the earlier
recommended estimator (EARLIER_ESTIMATOR). With
``--monitor`` it writes sweeps/estimator_envelope_monitor.yaml instead: the
recommended estimator alone, 60 s, with the health monitor on (its alarms
column is the false-alarm check). To rerun the map on another plant, add
the plant's fields to ``SET`` (e.g. a friction model) and write again.

``--estimator NAME`` maps that estimator alone (half the points);
``--keep-runs`` keeps each point's run, whose summary.json holds what its
trustworthy verdicts were judged from, so that ``map --rejudge`` judges
them again with this checkout's criterion (gantry_twin.health.confidence.judge)
without running anything.

``map`` prints, per estimator, the largest |error| of M, B, Af over the
map, the share of points marked trustworthy and the largest error among
those, and draws one heat map per estimator and shape/payload (cells: the
point's worst |error| of M1..Af2, %; a cell with an untrustworthy estimate
is marked ``u``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
SPEEDS_M_S = (0.02, 0.05, 0.1, 0.2, 0.4, 0.6)
SIZES_M = (0.02, 0.05, 0.1, 0.2)
PAYLOADS_KG = (0.0, 5.0)
#: ``--corners``: the map's edges and middle only (a quicker monitor check).
CORNER_SPEEDS_M_S = (0.02, 0.05, 0.2, 0.6)
CORNER_SIZES_M = (0.02, 0.2)
#: The scenario's largest rate (TimingSpec.rate_rad_s).
RATE_MAX_RAD_S = 20.0
#: "earlier": the earlier recommended estimator (50 Hz filters, Sf of the differenced velocity, no reversal gate).
EARLIER_ESTIMATOR = {"filter_hz": [50.0, 50.0], "least_squares": {"kappa": 0.7}, "gamma_d": [3.0e4, 3.0e4]}
ESTIMATORS = ("paper", "recommended")
PARAMETERS = ("M1", "M2", "B1", "B2", "Af1", "Af2")
#: Every point: 30 s (the paper's), the estimates averaged over the last 10 s (several laps of the fast
#: contours, a sixth of the slowest's 63 s lap). The plant's own fields go here too.
#: The map is of the ideal plant (plant.model: paper, the paper's model: its true B, Af are exactly the Coulomb +
#: viscous friction the estimator models); docs/estimator-envelope.md's numbers were measured there.
PLANT = {"plant.model": "paper"}
SET = {**PLANT, "duration_s": 30.0, "window_s": [10.0, 30.0], "estimates_window_s": [20.0, 30.0]}
MONITOR_SET = {
    **PLANT,
    "duration_s": 60.0,
    "window_s": [10.0, 60.0],
    "estimates_window_s": [50.0, 60.0],
    "monitor.enable": True,
}


def contours(speeds: tuple[float, ...] = SPEEDS_M_S, sizes: tuple[float, ...] = SIZES_M) -> list[dict]:
    """Circle and ellipse at every speed and size whose rate is allowed, slowest first."""
    out = []
    for shape in ("circle", "ellipse"):
        for size in sizes:
            for speed in speeds:
                rate = round(speed / size, 6)
                if rate > RATE_MAX_RAD_S:
                    continue
                timing = {"rate_rad_s": rate, "start": "on_path"}
                if shape == "circle":
                    out.append({"type": "circle", "radius_m": size, "centre_m": [0.0, 0.0], "timing": timing})
                else:
                    half = size / 2.0
                    out.append(
                        {
                            "type": "ellipse",
                            "semi_x_m": size,
                            "semi_y_m": half,
                            "centre_m": [0.0, half],
                            "timing": timing,
                        }
                    )
    return out


def write_sweep(
    monitor: bool, earlier: bool = False, corners: bool = False, estimator: str | None = None, keep_runs: bool = False
) -> Path:
    name = "estimator_envelope_monitor" if monitor else "estimator_envelope"
    if monitor:
        estimators = ["recommended"]
    else:
        estimators = [*([estimator] if estimator else ESTIMATORS), *([EARLIER_ESTIMATOR] if earlier else [])]
    spec = {
        "description": (
            "DIARC estimates over peak speed 0.02-0.6 m/s and size 0.02-0.2 m, circle and ellipse, "
            + ("0 and 5 kg, recommended estimator, 60 s with the health monitor" if monitor else "0 and 5 kg, ")
            + ("" if monitor else f"{estimator or 'paper and recommended'} estimator{'' if estimator else 's'}, 30 s")
        ),
        "scenario": "no_load_circle",
        "set": MONITOR_SET if monitor else SET,
        "axes": [
            {"field": "contour", "values": contours(*((CORNER_SPEEDS_M_S, CORNER_SIZES_M) if corners else ()))},
            {"field": "payload.mass_kg", "values": list(PAYLOADS_KG)},
            {"field": "controller.options.estimator", "values": estimators},
        ],
        "plots": ["error_pct_M1", "error_pct_B1", "error_pct_Af1"],
        **({"keep_runs": True} if keep_runs else {}),
    }
    path = ROOT / "sweeps" / f"{name}.yaml"
    flags = {"--monitor": monitor, "--earlier-estimator": earlier, "--corners": corners}
    flags[f"--estimator {estimator}"] = estimator
    flags["--keep-runs"] = keep_runs
    given = "".join(f" {flag}" for flag, on in flags.items() if on)
    header = f"# Written by benchmarks/estimator_envelope.py write{given}: edit there.\n"
    path.write_text(header + yaml.safe_dump(spec, sort_keys=False, default_flow_style=None, width=200))
    return path


def rejudge(row: dict, runs: Path) -> None:
    """Judge the row's estimates again with this checkout's criterion, from the kept run's summary.json
    (its ``confidence`` statistics: no simulation)."""
    from gantry_twin.health.confidence import judge
    from gantry_twin.health.excitation import ExcitationSettings
    from gantry_twin.outputs.summary import RunSummary
    from gantry_twin.plant.model import THETA_NAMES

    summary = RunSummary.read(runs / row["key"] / "summary.json")
    if summary.confidence is None:
        return
    stats = summary.confidence.model_dump()
    if np.shape(stats["friction_moment"]) != (2, 2, 4):
        raise SystemExit(f"{runs / row['key']}: judged from an older criterion's sums; run the sweep again")
    estimate = np.array([summary.estimates[name].estimate for name in THETA_NAMES])
    for name, verdict in judge(stats, estimate, ExcitationSettings()).items():
        row[f"trustworthy_{name}"] = verdict["trustworthy"]


def load(results: Path, runs: Path | None = None) -> list[dict]:
    import pyarrow.parquet as pq

    rows = [r for r in pq.read_table(results).to_pylist() if r["status"] == "ok"]
    for r in rows:
        if runs is not None:
            rejudge(r, runs)
        c = json.loads(r["contour"])
        r["shape"] = c["type"]
        r["size_m"] = c.get("radius_m", c.get("semi_x_m"))
        r["speed_m_s"] = round(r["size_m"] * c["timing"]["rate_rad_s"], 6)
        est = r["controller.options.estimator"]
        r["estimator"] = est if est in ("paper", "recommended") else "earlier"
        r["worst_pct"] = max(abs(r[f"error_pct_{p}"]) for p in PARAMETERS)
        flags = [r.get(f"trustworthy_{p}") for p in PARAMETERS]
        r["trusted"] = [bool(f) if f is not None else True for f in flags]
        r["worst_trusted_pct"] = max(
            [abs(r[f"error_pct_{p}"]) for p, ok in zip(PARAMETERS, r["trusted"], strict=True) if ok], default=0.0
        )
    return rows


def summarise(rows: list[dict]) -> None:
    for est in ("paper", "earlier", "recommended"):
        mine = [r for r in rows if r["estimator"] == est]
        if not mine:
            continue
        worst = max(mine, key=lambda r: r["worst_pct"])
        all_trusted = sum(all(r["trusted"]) for r in mine)
        trusted_estimates = sum(sum(r["trusted"]) for r in mine)
        worst_t = max(mine, key=lambda r: r["worst_trusted_pct"])
        within = sum(r["worst_pct"] <= 5.0 for r in mine)
        print(
            f"{est:12s} {len(mine)} points: worst |error| {worst['worst_pct']:.1f} % "
            f"({worst['shape']} {worst['size_m']} m {worst['speed_m_s']} m/s {worst['payload.mass_kg']} kg); "
            f"all within 5 %: {within}/{len(mine)}; every estimate trustworthy: {all_trusted}/{len(mine)} points, "
            f"{trusted_estimates}/{6 * len(mine)} estimates; "
            f"worst trusted |error| {worst_t['worst_trusted_pct']:.2f} % "
            f"({worst_t['shape']} {worst_t['size_m']} m {worst_t['speed_m_s']} m/s)"
        )
        per = ", ".join(
            f"{p} {sum(r['trusted'][i] for r in mine)}/{sum(abs(r[f'error_pct_{p}']) <= 5.0 for r in mine)}"
            for i, p in enumerate(PARAMETERS)
        )
        within = sum(abs(r[f"error_pct_{p}"]) <= 5.0 for r in mine for p in PARAMETERS)
        print(f"{'':12s} estimates within 5 %: {within}/{6 * len(mine)}; trusted / within 5 % per parameter: {per}")
        alarms = [r.get("alarms") for r in mine if r.get("alarms") is not None]
        if alarms:
            print(
                f"{'':12s} monitor alarms: {sum(alarms)} over {len(alarms)} points "
                f"({sum(a > 0 for a in alarms)} with any)"
            )


def draw(rows: list[dict], figure: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    estimators = [e for e in ("paper", "earlier", "recommended") if any(r["estimator"] == e for r in rows)]
    panels = [(s, m) for s in ("circle", "ellipse") for m in PAYLOADS_KG]
    from gantry_twin.outputs.plots import DPI

    fig, axes = plt.subplots(
        len(estimators), len(panels), figsize=(3.4 * len(panels), 2.5 * len(estimators)), layout="constrained"
    )
    axes = np.atleast_2d(axes)
    for i, est in enumerate(estimators):
        for j, (shape, mass) in enumerate(panels):
            ax = axes[i, j]
            grid = np.full((len(SIZES_M), len(SPEEDS_M_S)), np.nan)
            marks = {}
            for r in rows:
                if r["estimator"] == est and r["shape"] == shape and r["payload.mass_kg"] == mass:
                    a, b = SIZES_M.index(r["size_m"]), SPEEDS_M_S.index(r["speed_m_s"])
                    grid[a, b] = r["worst_pct"]
                    marks[a, b] = "" if all(r["trusted"]) else "u"
            image = ax.imshow(np.log10(np.clip(grid, 0.01, 100)), origin="lower", cmap="RdYlGn_r", vmin=-2, vmax=2)
            for (a, b), mark in marks.items():  # whole per cent from 10 up: "58.3u58.3u" ran across the cells
                value = f"{grid[a, b]:.0f}" if grid[a, b] >= 10 else f"{grid[a, b]:.1f}"
                ax.text(b, a, value + mark, ha="center", va="center", fontsize=7)
            ax.set_xticks(range(len(SPEEDS_M_S)), [f"{s:g}" for s in SPEEDS_M_S], fontsize=7)
            ax.set_yticks(range(len(SIZES_M)), [f"{s:g}" for s in SIZES_M], fontsize=7)
            ax.set_title(f"{est}: {shape}, {mass:g} kg", fontsize=8)
            if i == len(estimators) - 1:
                ax.set_xlabel("peak speed (m/s)", fontsize=8)
            if j == 0:
                ax.set_ylabel("radius / semi-x (m)", fontsize=8)
    fig.colorbar(image, ax=axes, shrink=0.8, label="log10 worst |error| of M, B, Af (%)")
    fig.suptitle("worst |error| of M1, M2, B1, B2, Af1, Af2 per point (%); u: one of them not trusted", fontsize=9)
    fig.savefig(figure, dpi=DPI)
    print(f"figure: {figure}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    w = sub.add_parser("write", help="write the sweep file")
    w.add_argument("--monitor", action="store_true", help="the 60 s monitor sweep instead")
    w.add_argument("--earlier-estimator", action="store_true", help="also the earlier recommended estimator")
    w.add_argument("--corners", action="store_true", help=f"only speeds {CORNER_SPEEDS_M_S}, sizes {CORNER_SIZES_M}")
    w.add_argument("--estimator", choices=ESTIMATORS, help="this estimator alone (half the map)")
    w.add_argument(
        "--keep-runs", action="store_true", help="keep each point's run (trace.parquet) for `confidence` re-evaluation"
    )
    m = sub.add_parser("map", help="summarise a finished sweep and draw the map")
    m.add_argument(
        "results", type=Path, nargs="+", help="results.parquet of one or more sweeps (e.g. one per estimator)"
    )
    m.add_argument("--figure", type=Path)
    m.add_argument(
        "--rejudge",
        action="store_true",
        help="judge the estimates again with this checkout's criterion from the kept runs (a sweep with --keep-runs)",
    )
    args = parser.parse_args(argv)
    if args.command == "write":
        print(write_sweep(args.monitor, args.earlier_estimator, args.corners, args.estimator, args.keep_runs))
        return 0
    rows = [row for path in args.results for row in load(path, path.parent / "runs" if args.rejudge else None)]
    summarise(rows)
    if args.figure:
        draw(rows, args.figure)
    return 0


if __name__ == "__main__":
    sys.exit(main())
