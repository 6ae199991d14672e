"""Feed planning (gantry_twin.gcode.planner): the sampled reference against independent computations.

Limits are checked on the reference sampled at the loop's 0.2 ms by finite differences of the positions
(independent of the planner's own derivatives); tolerances by a brute-force distance to the programmed
lines and arcs written here.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gantry_twin.gcode import parse_program, read_program
from gantry_twin.gcode.planner import BLEND, STOP, AxisLimits, PlanOptions, default_limits, plan_program

PROGRAMS = sorted((Path(__file__).resolve().parents[1] / "programs").glob("*.ngc"))
TS = 2e-4


def sampled(plan, dt=TS):
    t = np.arange(0.0, plan.duration_s + dt, dt)
    return plan.sample(t)


def finite_difference_peaks(q, dt=TS):
    """max |v|, |a|, |j| per axis of positions sampled every dt (first, second and third differences)."""
    return [np.abs(np.diff(q, order, axis=0) / dt**order).max(axis=0) for order in (1, 2, 3)]


def assert_within_limits(plan, limits: AxisLimits, rel=1e-3):
    peaks = finite_difference_peaks(sampled(plan).q_m)
    for peak, limit, what in zip(
        peaks, (limits.velocity_m_s, limits.acceleration_m_s2, limits.jerk_m_s3), ("v", "a", "j"), strict=True
    ):
        assert np.all(peak <= np.asarray(limit) * (1 + rel)), f"{what}: {peak} > {limit}"


def test_default_limits_follow_the_plant():
    limits = default_limits()
    # Half of 10 V x 69 N/V on 8.28 kg (X) and 34.5 kg (Y).
    assert limits.acceleration_m_s2 == pytest.approx((0.5 * 690 / 8.28, 0.5 * 690 / 34.5))
    assert limits.jerk_m_s3 == pytest.approx((0.5 * 690 / 8.28 / 0.02, 10.0 / 0.02))


@pytest.mark.parametrize("path", PROGRAMS, ids=[p.stem for p in PROGRAMS])
def test_limits_hold_on_the_shipped_programs(path):
    plan = plan_program(read_program(path))
    assert_within_limits(plan, plan.options.limits)
    s = plan.sample(np.array([0.0, plan.duration_s]))
    assert np.allclose(s.v_m_s, 0.0) and np.allclose(s.a_m_s2, 0.0)  # from rest, to rest
    assert s.q_m[0] == pytest.approx(plan.program.start_m, abs=1e-12)


def test_tight_limits_hold_too():
    limits = AxisLimits((0.3, 0.2), (2.0, 1.0), (40.0, 15.0))
    plan = plan_program(read_program(PROGRAMS[0].parent / "bracket.ngc"), PlanOptions(limits=limits))
    assert_within_limits(plan, limits)


def test_the_feed_is_reached_on_a_long_straight_block():
    plan = plan_program(parse_program("G0 X-200 Y-100\nG1 X200 Y100 F24000\nM30"))
    q = sampled(plan).q_m
    speed = np.linalg.norm(np.diff(q, axis=0), axis=1) / TS
    assert speed.max() == pytest.approx(0.4, rel=1e-3)
    assert np.mean(np.abs(speed - 0.4) < 1e-9) > 0.5  # most of the block at F


def test_the_circle_at_constant_speed_is_the_papers_circle():
    plan = plan_program(read_program(PROGRAMS[0].parent / "circle.ngc"))
    s = sampled(plan)
    assert np.allclose(np.linalg.norm(s.q_m, axis=1), 0.2, atol=1e-12)
    cruising = np.abs(np.linalg.norm(s.v_m_s, axis=1) - 0.4) < 1e-12
    assert cruising.sum() * TS > math.pi  # more than one lap
    assert np.allclose(s.dalpha_rad_s[cruising], -2.0) and np.allclose(s.ddalpha_rad_s2[cruising], 0.0, atol=1e-9)


def point_on(move, u):
    """Points at arc lengths u (m) of a move, from its definition."""
    if move.centre_m is None:
        direction = np.subtract(move.end_m, move.start_m) / move.length_m
        return np.asarray(move.start_m) + u[..., None] * direction
    c = move.centre_m
    angle = math.atan2(move.start_m[1] - c[1], move.start_m[0] - c[0]) + np.sign(move.sweep_rad) * u / move.radius_m
    return np.asarray(c) + move.radius_m * np.stack([np.cos(angle), np.sin(angle)], axis=-1)


def distance_to_moves(points, moves, coarse=4001):
    """Brute force: the nearest of ``coarse`` points along each move, refined by a ternary search around it."""
    best = np.full(len(points), np.inf)
    for m in moves:
        u = np.linspace(0.0, m.length_m, coarse)
        along = point_on(m, u)
        # The nearest coarse point, a block of points at a time, each norm as np.linalg.norm computes it (sqrt of
        # x*x + y*y): the same argmin without a (points, coarse, 2) array of hundreds of MB (a long trace against
        # 4001 points; memory traffic and the reduction over an axis of two were most of the time).
        i = np.concatenate(
            [
                np.argmin(np.sqrt((x - along[:, 0]) ** 2 + (y - along[:, 1]) ** 2), axis=1)
                for x, y in (
                    (block[:, :1], block[:, 1:2]) for block in np.array_split(points, max(1, len(points) // 256))
                )
            ]
        )
        lo, hi = u[np.maximum(i - 1, 0)], u[np.minimum(i + 1, coarse - 1)]
        for _ in range(80):
            a, b = lo + (hi - lo) / 3, hi - (hi - lo) / 3
            da = np.linalg.norm(points - point_on(m, a), axis=1)
            db = np.linalg.norm(points - point_on(m, b), axis=1)
            lo, hi = np.where(da < db, lo, a), np.where(da < db, b, hi)
        best = np.minimum(best, np.linalg.norm(points - point_on(m, 0.5 * (lo + hi)), axis=1))
    return best


def blend_deviations(plan):
    """(deviation, tolerance) of every blended corner: the planned path in the blend against the two moves."""
    out = []
    for k in np.flatnonzero(plan.kind == BLEND):
        a, b = plan.moves[k - 1], plan.moves[k]
        t = np.linspace(plan.t0_s[k], plan.end_s[k - 1], 200)
        q = plan.sample(t).q_m
        out.append((distance_to_moves(q, [a, b]).max(), a))
    return out


@pytest.mark.parametrize("name", ["polygon_g64.ngc", "rounded_rectangle.ngc", "bracket.ngc"])
def test_blends_stay_within_the_tolerance(name):
    plan = plan_program(read_program(PROGRAMS[0].parent / name))
    deviations = blend_deviations(plan)
    assert deviations
    for deviation, move in deviations:
        assert deviation <= move.tolerance_m + 2e-8, (move.line, deviation, move.tolerance_m)


def test_g61_corners_are_passed_at_rest_through_the_corner_point():
    plan = plan_program(read_program(PROGRAMS[0].parent / "polygon_g61.ngc"))
    corners = [k for k in range(1, len(plan.moves)) if plan.kind[k] == STOP]
    assert len(corners) == len(plan.moves) - 1
    for k in corners:
        corner = np.asarray(plan.moves[k - 1].end_m)
        t = np.linspace(plan.end_s[k - 1], plan.t0_s[k], 101)
        s = plan.sample(t)
        assert np.abs(s.q_m - corner).max() <= 1e-9
        assert np.abs(s.v_m_s).max() <= 1e-12 and np.abs(s.a_m_s2).max() <= 1e-9
        before = plan.sample(plan.end_s[k - 1] - np.array([1e-2, 1e-3]))
        assert np.all(np.linalg.norm(before.q_m - corner, axis=1) > 1e-9)  # moving until then


def test_alpha_and_its_rates_agree_and_stay_finite():
    plan = plan_program(read_program(PROGRAMS[0].parent / "rounded_rectangle.ngc"))
    dt = 1e-5
    s = sampled(plan, dt)
    assert np.all(np.isfinite(s.ddalpha_rad_s2))
    assert np.abs(np.diff(s.alpha_rad)).max() < 0.05  # continuous: no wraps, no jumps
    fd = np.diff(s.alpha_rad) / dt
    mid = 0.5 * (s.dalpha_rad_s[1:] + s.dalpha_rad_s[:-1])
    assert np.abs(fd - mid).max() < 1e-3 * max(1.0, np.abs(mid).max())


def test_a_g61_stop_turns_alpha_smoothly_in_place():
    plan = plan_program(parse_program("G61\nG1 X100 F12000\nY100\nM30"))
    t = np.linspace(plan.end_s[0], plan.t0_s[1], 101)
    s = plan.sample(t)
    assert s.alpha_rad[0] == pytest.approx(0.0) and s.alpha_rad[-1] == pytest.approx(0.5 * math.pi)
    assert np.allclose(s.q_m, [0.1, 0.0]) and np.all(np.diff(s.alpha_rad) >= 0)


# ----------------------------------------------------------------------------------- random programs
@st.composite
def programs(draw):
    x, y = draw(st.floats(-150, 150)), draw(st.floats(-150, 150))
    lines = [f"G0 X{x:.3f} Y{y:.3f}"]
    mode = draw(st.sampled_from(["G61", "G64", "G64 P0.01", "G64 P0.1", "G64 P1"]))
    lines.append(mode)
    for _ in range(draw(st.integers(1, 6))):
        feed = draw(st.floats(600, 60000))
        angle = draw(st.floats(-math.pi, math.pi))
        length = draw(st.floats(1.0, 120.0))
        nx, ny = x + length * math.cos(angle), y + length * math.sin(angle)
        if abs(nx) > 240 or abs(ny) > 240:
            continue
        if draw(st.booleans()):
            lines.append(f"G1 X{nx:.4f} Y{ny:.4f} F{feed:.1f}")
        else:
            r = 0.5 * length * draw(st.floats(1.01, 4.0)) * draw(st.sampled_from([1, -1]))
            lines.append(f"G{draw(st.sampled_from([2, 3]))} X{nx:.4f} Y{ny:.4f} R{r:.4f} F{feed:.1f}")
        x, y = float(f"{nx:.4f}"), float(f"{ny:.4f}")
    return "\n".join(lines) + "\nM30\n"


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(programs())
def test_limits_and_tolerances_hold_on_random_programs(text):
    try:
        program = parse_program(text, name="random.ngc")
    except Exception as error:  # an arc through the travel's edge
        assert "outside the travel" in str(error)
        return
    if not program.moves:
        return
    plan = plan_program(program)
    assert_within_limits(plan, plan.options.limits)
    for deviation, move in blend_deviations(plan):
        assert deviation <= move.tolerance_m + 2e-8
    end = plan.sample(np.array([plan.duration_s]))
    assert end.q_m[0] == pytest.approx(program.moves[-1].end_m, abs=1e-9)
