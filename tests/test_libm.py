"""The loop's reference arrays come from the C library, not from numpy's CPU-dispatched SIMD loops.

numpy's float64 sin, cos and arctan2 take their last bits from whichever SIMD
implementation the CPU selects, so a reference computed with them differs
between machines and the pinned trace digests with it. The test replaces
numpy's functions with ones that are one ulp off: a reference that still
called them would change.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from gantry_twin.gcode import read_program
from gantry_twin.gcode.planner import plan_program
from gantry_twin.numerics import libm
from gantry_twin.paths.contours import TimingLaw, circle, paper_ellipse, reference

PROGRAM = Path(__file__).resolve().parents[1] / "programs" / "bracket.ngc"


def one_ulp_off(function):
    def perturbed(*args, **kwargs):
        return np.nextafter(function(*args, **kwargs), np.inf)

    return perturbed


def references():
    t = np.arange(0.0, 2.0, 2e-4)
    plan = plan_program(read_program(PROGRAM))
    return {
        "circle": reference(circle(), TimingLaw(2.0), t),
        "ellipse": reference(paper_ellipse(), TimingLaw(2.0), t),
        "program": plan.reference(np.linspace(0.0, plan.duration_s, 20_001)),
    }


def test_the_reference_does_not_use_numpys_transcendental_loops(monkeypatch):
    before = references()
    for name in ("sin", "cos", "arctan2", "arctan"):
        monkeypatch.setattr(np, name, one_ulp_off(getattr(np, name)))
    after = references()
    for case, ref in before.items():
        for field in ("q_d", "dq_d", "ddq_d", "alpha", "dalpha", "ddalpha"):
            assert np.array_equal(getattr(ref, field), getattr(after[case], field)), f"{case}.{field}"


@pytest.mark.parametrize(("ours", "theirs"), [(libm.sin, math.sin), (libm.cos, math.cos)])
def test_unary_functions_are_the_c_librarys(ours, theirs):
    x = np.random.default_rng(1).uniform(-50.0, 50.0, (40, 25))
    got = ours(x)
    assert got.shape == x.shape and got.dtype == np.float64
    assert got.tolist() == [[theirs(v) for v in row] for row in x.tolist()]


def test_atan2_broadcasts_like_numpy_and_is_the_c_librarys():
    rng = np.random.default_rng(2)
    y, x = rng.normal(size=(30, 1)), rng.normal(size=(1, 7))
    got = libm.atan2(y, x)
    assert got.shape == (30, 7)
    assert got.tolist() == [[math.atan2(a, b) for b in x[0]] for a in y[:, 0]]
    assert libm.atan2(0.0, -1.0).shape == () and float(libm.atan2(0.0, -1.0)) == math.pi
