"""Shared fixtures: paper scenarios as small helpers (no scenario files needed)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gantry_twin import Payload, Plant, SensingConfig, TimingLaw, circle, paper_ellipse, simulate
from gantry_twin.controllers import create

CIRCLE_RATE = 2.0  # rad/s: 0.4 m/s on a 0.2 m radius (paper 5.1)
ELLIPSE_RATE = 3.0  # rad/s (paper 5.2)


def contour(name: str):
    """(path, timing law, period s) of the paper's circle or ellipse, on_path start."""
    if name == "circle":
        return circle(), TimingLaw(CIRCLE_RATE), 2 * math.pi / CIRCLE_RATE
    return paper_ellipse(), TimingLaw(ELLIPSE_RATE), 2 * math.pi / ELLIPSE_RATE


def step_on_y(value_v: float = 0.6, start_s: float = 1.86, end_s: float = 4.86):
    """The paper's Set 3 disturbance: value_v on the Y input from start_s to end_s."""

    def disturbance(t: np.ndarray) -> np.ndarray:
        d = np.zeros((t.size, 2))
        d[(t >= start_s) & (t < end_s), 1] = value_v
        return d

    return disturbance


def run(controller: str, contour_name: str = "circle", duration_s: float = 7.0, payload_kg: float = 0.0,
        sensing: SensingConfig | None = None, disturbance=None, **options):
    """Simulate one paper-style run; returns (trace, period s)."""
    path, timing, period = contour(contour_name)
    trace = simulate(Plant(Payload(payload_kg)), path, timing, create(controller, **options), duration_s,
                     sensing=sensing, disturbance=disturbance)
    return trace, period


@pytest.fixture(scope="session")
def circle_set1_traces():
    """Circle, no load, default sensing, 7 s: DRC, DARC, DIARC (used by several tests)."""
    return {name: run(name)[0] for name in ("drc", "darc", "diarc")}
