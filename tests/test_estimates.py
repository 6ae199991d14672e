"""DIARC's physical parameter estimates against the model's true values.

Steady-state estimate = mean theta^ over the last period of a 30 s run
(docs/scenarios.md; 15 s for the recommended estimator, settled long before),
compared with the reference machine (typed in tests/helpers.py, not read back from the code). Checked on the estimates
themselves, not only the contour error: a zero-order-hold position filter or
a wrong regressor keeps the contour error small but pins the estimates at
their bounds.
"""

from __future__ import annotations

import numpy as np
import pytest

from gantry_twin import SensingConfig
from gantry_twin.controllers import RECOMMENDED_ESTIMATOR, EstimatorSettings
from gantry_twin.run import execute, summarise
from gantry_twin.scenario import build, load_scenario, shipped

from .helpers import THETA_MIN, deviation_pct, run, spec_theta

#: Every test here is a 15-30 s closed-loop run (seconds each).
pytestmark = pytest.mark.slow

PHYSICAL = ("M1", "M2", "B1", "B2", "Af1", "Af2")
CASES = [(c, load) for c in ("circle", "ellipse") for load in (0.0, 5.0)]
DURATION_S = 30.0


#: The recommended estimator (10 Hz filters, kappa 0.7 1/s) has settled by 12 s on these contours: its last-period
#: means at 15 s and at 30 s agree to 0.05 % of each value, so a 15 s run judges the same steady state. The paper's
#: estimator is still converging at 20 s (B and Af 4-6 % off): its runs stay 30 s long.
RECOMMENDED_DURATION_S = 15.0


def steady_errors(contour_name, payload_kg, sensing, estimator, duration_s=DURATION_S):
    """% deviation of each physical estimate from the reference value, and the last period's theta^ (samples x 8)."""
    trace, period = run("diarc", contour_name, duration_s, payload_kg, sensing=sensing, estimator=estimator)
    last_period = trace.controller_state["theta_hat"][trace.t_s >= duration_s - period]
    errors = deviation_pct(last_period.mean(axis=0)[:6], spec_theta(payload_kg)[:6])
    return dict(zip(PHYSICAL, errors, strict=True)), last_period


@pytest.mark.parametrize(("contour_name", "payload_kg"), CASES)
def test_ideal_sensing_paper_filters_within_5_percent(contour_name, payload_kg):
    errors, _ = steady_errors(contour_name, payload_kg, SensingConfig.ideal(), EstimatorSettings())
    for name in PHYSICAL:
        assert abs(errors[name]) < 5.0, f"{name}: {errors[name]:+.2f} %"


@pytest.mark.parametrize(("contour_name", "payload_kg"), CASES)
def test_encoder_with_recommended_estimator_within_5_percent(contour_name, payload_kg):
    errors, last_period = steady_errors(
        contour_name, payload_kg, SensingConfig(), RECOMMENDED_ESTIMATOR, RECOMMENDED_DURATION_S
    )
    for name in PHYSICAL:
        assert abs(errors[name]) < 5.0, f"{name}: {errors[name]:+.2f} %"
    # No unmodelled input here, so the nominal disturbance estimates stay near 0 V.
    assert np.all(np.abs(last_period.mean(axis=0)[6:]) < 0.02)


def test_paper_filters_with_encoder_bias_m1_on_the_circle():
    """Quantisation noise in x_f'' (the estimator's filters, docs/equations.md; gain ~wn^2, ~0.36 m/s^2 rms
    with the 250 Hz filter) against the circle's X acceleration (0.8 m/s^2 amplitude, 0.57 rms) shrinks M1 by
    errors in variables: by ~24 % (expected); 1 - 0.57^2 / (0.57^2 + 0.36^2) = 29 % for a lone regressor. The
    twin reproduces it, which is why its recommended estimator uses 10 Hz filters. M1's lower bound
    (0.05 V s^2/m) is -58 %: an estimate pinned there is a different failure and must not pass."""
    errors, last_period = steady_errors("circle", 0.0, SensingConfig(), EstimatorSettings())
    assert -32.0 < errors["M1"] < -18.0, f"M1 {errors['M1']:+.1f} %"
    assert last_period[:, 0].min() > 1.5 * THETA_MIN[0]  # well inside the bounds for the whole last period
    # The bias is M1's: the other physical parameters stay close.
    for name in PHYSICAL[1:]:
        assert abs(errors[name]) < 6.0, f"{name}: {errors[name]:+.2f} %"


#: The slow circle (docs/estimator-envelope.md, on the ideal plant as its map): r 0.05 m at 1 rad/s (0.05 m/s
#: peak), 30 s. The earlier
#: recommended estimator (50 Hz filters, Sf(v) of the differenced velocity) gave M1 -17.7 %, B1 -21.3 %,
#: B2 -20.2 % there.
SLOW_CIRCLE = ("contour.radius_m=0.05", "contour.timing.rate_rad_s=1.0", "plant.model=paper")  # the map's plant
EARLIER_ESTIMATOR = (
    "controller.options.estimator={filter_hz: [50, 50], least_squares: {kappa: 0.7}, gamma_d: [3e4, 3e4]}"
)


def slow_circle_estimates(estimator_override: str) -> dict:
    """summary.json's estimates (with their trustworthiness) of the slow circle run as ``gantry-twin run`` runs it."""
    built = build(load_scenario(shipped("no_load_circle"), [*SLOW_CIRCLE, estimator_override]))
    return summarise(built, execute(built)).as_dict()["estimates"]


def test_slow_circle_recommended_estimator_within_5_percent():
    estimates = slow_circle_estimates("controller.options.estimator=recommended")
    for name in PHYSICAL:
        assert abs(estimates[name]["error_pct"]) < 5.0, f"{name}: {estimates[name]['error_pct']:+.2f} %"
        # ... and says so: accurate estimates are not flagged by a too strict criterion
        assert estimates[name]["trustworthy"], f"{name}: {estimates[name]}"


def test_slow_circle_biased_estimates_are_marked_untrustworthy():
    """The earlier estimator is biased on the slow circle; summary.json must not call those estimates trustworthy."""
    estimates = slow_circle_estimates(EARLIER_ESTIMATOR)
    biased = [name for name in PHYSICAL if abs(estimates[name]["error_pct"]) > 5.0]
    assert {"M1", "B1", "B2"} <= set(biased)  # the earlier estimator's bias, reproduced
    for name in biased:
        assert estimates[name]["trustworthy"] is False, f"{name}: {estimates[name]}"
        assert estimates[name]["why"]
