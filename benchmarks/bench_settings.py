"""The runs behind the ranges of the estimator and controller settings (docs/scenarios.md).

    PYTHONPATH=src python benchmarks/bench_settings.py [--seconds 10] [--only filter_hz,ks_v_s_m]

Each setting is run at values inside and beyond its declared range: the named controller on the paper's
circle, no load, the default (quantised) sensing, ``--seconds`` of simulation, compiled backend. Printed per
run: max |eps_c| and the estimate errors of M1, M2, B1, B2, Af1, Af2 (mean theta^ over the last 3 s against
the model's truth, %) and how far theta^ moved from theta0 (the largest |theta^ - theta0| of M, B, Af, volt
units). Values beyond a range are set past the settings' checks (``unchecked``): that is what the ranges
now refuse.
"""

from __future__ import annotations

import argparse
import copy
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import ArcGains, EstimatorSettings, create
from gantry_twin.controllers.arc import DARC_GAMMA
from gantry_twin.numerics.estimation import LeastSquaresSettings
from gantry_twin.plant.sensing import SensingConfig


def unchecked(settings: Any, **fields: Any) -> Any:
    """A copy of a frozen settings object with ``fields`` set, past its range checks."""
    out = copy.copy(settings)
    for name, value in fields.items():
        object.__setattr__(out, name, value)
    return out


def estimator(**fields: Any) -> dict[str, Any]:
    return {"estimator": unchecked(EstimatorSettings(), **fields)}


def least_squares(**fields: Any) -> dict[str, Any]:
    return estimator(least_squares=unchecked(LeastSquaresSettings(), **fields))


def gains(**fields: Any) -> dict[str, Any]:
    return {"gains": unchecked(ArcGains(), **fields)}


def pd(name: str, value: float) -> dict[str, Any]:
    return {name: (value, value)}


#: setting -> (controller, values, options of one value).
STUDIES: dict[str, tuple[str, tuple[float, ...], Callable[[float], dict[str, Any]]]] = {
    "filter_hz": ("diarc", (1e-3, 1, 2, 5, 50, 250, 300, 400, 500, 1000), lambda v: estimator(filter_hz=(v, v))),
    "filter_zeta": ("diarc", (1e-3, 0.05, 0.1, 0.7, 5), lambda v: estimator(filter_hz=(50.0, 50.0), filter_zeta=v)),
    "nu": ("diarc", (0, 0.1, 1, 10), lambda v: least_squares(nu=v)),
    "kappa": ("diarc", (0, 0.1, 10, 100, 1e5), lambda v: least_squares(kappa=v)),
    "rho_max": ("diarc", (1e-3, 1, 500, 1e8, 1e9), lambda v: least_squares(rho_max=v, kappa=0.7)),
    "gamma0_diag (x paper)": (
        "diarc",
        (1e-6, 1e-3, 1e-2, 1, 1e4),
        lambda v: least_squares(gamma0_diag=tuple(v * g for g in LeastSquaresSettings().gamma0_diag)),
    ),
    "gamma_d": ("diarc", (0, 1e4, 1e5, 1e6, 1e7), lambda v: estimator(gamma_d=(v, v))),
    "lambda_1_s": ("diarc", (0.1, 1, 10, 100, 5000, 1e4, 1e5), lambda v: gains(lambda_1_s=(v, v))),
    "ks_v_s_m": ("diarc", (0.1, 1, 10, 100, 1000, 1200, 2000, 3000), lambda v: gains(ks_v_s_m=(v, v))),
    "friction_slope_s_m": ("diarc", (1, 10, 100, 9000, 1e6, 1e8), lambda v: gains(friction_slope_s_m=v)),
    "darc gamma (x paper)": ("darc", (1, 100, 1e4), lambda v: {"gamma": tuple(v * g for g in DARC_GAMMA)}),
    "kp_v_m": ("pd", (1e3, 1e4, 1e5, 1e6, 1e7), lambda v: pd("kp_v_m", v)),
    "kd_v_s_m": ("pd", (10, 100, 1000, 1500, 3000), lambda v: pd("kd_v_s_m", v)),
    "kv_v_s_m": ("pd", (0.5, 10, 100), lambda v: pd("kv_v_s_m", v)),
    "ka_v_s2_m": ("pd", (0.12, 2, 10, 100), lambda v: pd("ka_v_s2_m", v)),
}


def run(controller: str, options: dict[str, Any], seconds: float, plant: Plant) -> str:
    c = create(controller, **options)
    trace = simulate(plant, circle(), TimingLaw(2.0), c, duration_s=seconds, sensing=SensingConfig())
    last = trace.t_s > seconds - 3.0
    eps_um = np.abs(trace.eps_c_m[last]).max() * 1e6
    theta = trace.controller_state.get("theta_hat")
    if theta is None:
        return f"max eps_c {eps_um:9.2f} um"
    truth = trace.true_theta[:6]
    errors = 100.0 * (theta[last].mean(axis=0)[:6] - truth) / truth
    moved = np.abs(theta[-1, :6] - theta[0, :6]).max()
    return f"max eps_c {eps_um:9.2f} um  errors % {np.array2string(errors, precision=1)}  moved {moved:.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--only", default="", help="comma-separated settings (default: all)")
    args = parser.parse_args()
    only = [s for s in args.only.split(",") if s]
    plant = Plant()
    for setting, (controller, values, options) in STUDIES.items():
        if only and setting not in only:
            continue
        print(f"{setting} ({controller})", flush=True)
        for value in values:
            started = time.perf_counter()
            result = run(controller, options(value), args.seconds, plant)
            print(f"  {value:<10g} {result}  [{time.perf_counter() - started:.1f} s]", flush=True)


if __name__ == "__main__":
    main()
