"""Desired contours and timing laws against finite differences.

Every analytic derivative is compared with a central difference of the
quantity one order below it, for both contours and both timing laws
(``on_path`` and ``rest``, sampled inside the start ramp as well as after it).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from gantry_twin.paths.contours import (
    ReferenceStream,
    TimingLaw,
    circle,
    contour_error,
    paper_ellipse,
    reference,
    tangent_angle,
)

PATHS = {"circle": (circle(), 2.0), "ellipse": (paper_ellipse(), 3.0)}
RNG_SEED = 20100401
H_PHI = 1e-5  # rad
H_T = 1e-6  # s


def wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def central(f, x: np.ndarray, h: float) -> np.ndarray:
    return (f(x + h) - f(x - h)) / (2.0 * h)


def sample_times(timing: TimingLaw) -> np.ndarray:
    """Random times inside the ramp (if any) and after it, away from its two corners."""
    rng = np.random.default_rng(RNG_SEED)
    t = np.concatenate([rng.uniform(0.01, 0.49, 40), rng.uniform(0.51, 5.0, 40)])
    if timing.start == "rest":
        assert (t < timing.ramp_s).sum() >= 40  # the ramp is really exercised
    return t


@pytest.mark.parametrize("name", PATHS)
def test_curve_derivatives_match_finite_differences(name: str) -> None:
    path, _ = PATHS[name]
    phi = np.random.default_rng(RNG_SEED).uniform(-2 * np.pi, 4 * np.pi, 200)
    p, dp, ddp, dddp = path.derivatives(phi)
    scale = np.abs(p).max()
    for lower, upper in ((0, dp), (1, ddp), (2, dddp)):
        fd = central(lambda x, i=lower: path.derivatives(x)[i], phi, H_PHI)
        np.testing.assert_allclose(upper, fd, atol=1e-8 * scale)


@pytest.mark.parametrize("name", PATHS)
def test_tangent_angle_and_its_phi_derivatives(name: str) -> None:
    path, _ = PATHS[name]
    phi = np.random.default_rng(RNG_SEED).uniform(-2 * np.pi, 4 * np.pi, 200)
    alpha, a_phi, a_phiphi = tangent_angle(path, phi)
    # alpha is the direction of dp/dphi.
    _, dp, _, _ = path.derivatives(phi)
    unit = dp / np.linalg.norm(dp, axis=-1, keepdims=True)
    np.testing.assert_allclose(np.stack([np.cos(alpha), np.sin(alpha)], axis=-1), unit, atol=1e-12)
    fd_alpha = wrap(tangent_angle(path, phi + H_PHI)[0] - tangent_angle(path, phi - H_PHI)[0]) / (2 * H_PHI)
    np.testing.assert_allclose(a_phi, fd_alpha, rtol=1e-6, atol=1e-6)
    fd_aphi = central(lambda x: tangent_angle(path, x)[1], phi, H_PHI)
    np.testing.assert_allclose(a_phiphi, fd_aphi, rtol=1e-5, atol=1e-5)
    if name == "circle":  # constant curvature: alpha = phi, alpha_phi = 1
        np.testing.assert_allclose(a_phi, 1.0, atol=1e-12)
        np.testing.assert_allclose(a_phiphi, 0.0, atol=1e-12)


@pytest.mark.parametrize("start", ["on_path", "rest"])
@pytest.mark.parametrize("rate", [2.0, 3.0])
def test_timing_law_derivatives_match_finite_differences(start: str, rate: float) -> None:
    timing = TimingLaw(rate, start)
    t = sample_times(timing)
    phi, dphi, ddphi, dddphi = timing.derivatives(t)
    for lower, upper, scale in ((0, dphi, rate), (1, ddphi, rate / 0.5), (2, dddphi, rate / 0.25)):
        fd = central(lambda x, i=lower: timing.derivatives(x)[i], t, H_T)
        np.testing.assert_allclose(upper, fd, atol=1e-6 * scale)
    after = t > timing.settled_s
    np.testing.assert_allclose(dphi[after], rate)
    np.testing.assert_allclose(ddphi[after], 0.0)
    np.testing.assert_allclose(dddphi[after], 0.0)


def test_rest_start_is_smooth_at_both_ramp_corners() -> None:
    """phi', phi'', phi''' are continuous at t = 0 and at the end of the ramp (quintic smoothstep)."""
    timing = TimingLaw(2.0, "rest", ramp_s=0.5)
    for corner in (0.0, 0.5):
        before = np.array(timing.derivatives(np.array([corner - 1e-9])))[:, 0]
        after = np.array(timing.derivatives(np.array([corner + 1e-9])))[:, 0]
        np.testing.assert_allclose(before, after, atol=1e-6)
    phi, dphi, ddphi, dddphi = (x[0] for x in timing.derivatives(np.array([0.0])))
    assert phi == dphi == ddphi == dddphi == 0.0
    # After the ramp phi runs at the rate, half a ramp behind the on_path law.
    phi_late = timing.derivatives(np.array([3.0]))[0][0]
    assert phi_late == pytest.approx(2.0 * (3.0 - 0.25), rel=1e-12)


@pytest.mark.parametrize("start", ["on_path", "rest"])
@pytest.mark.parametrize("name", PATHS)
def test_reference_time_derivatives_match_finite_differences(name: str, start: str) -> None:
    path, rate = PATHS[name]
    timing = TimingLaw(rate, start)
    t = sample_times(timing)
    ref = reference(path, timing, t)
    lo, hi = reference(path, timing, t - H_T), reference(path, timing, t + H_T)
    np.testing.assert_allclose(ref.dq_d, (hi.q_d - lo.q_d) / (2 * H_T), atol=1e-7)
    np.testing.assert_allclose(ref.ddq_d, (hi.dq_d - lo.dq_d) / (2 * H_T), atol=1e-6)
    np.testing.assert_allclose(ref.dalpha, wrap(hi.alpha - lo.alpha) / (2 * H_T), atol=1e-5)
    np.testing.assert_allclose(ref.ddalpha, (hi.dalpha - lo.dalpha) / (2 * H_T), atol=1e-4)
    # alpha points along the motion wherever the reference moves.
    speed = np.linalg.norm(ref.dq_d, axis=1)
    moving = speed > 1e-6
    np.testing.assert_allclose(np.cos(ref.alpha[moving]), ref.dq_d[moving, 0] / speed[moving], atol=1e-12)
    np.testing.assert_allclose(np.sin(ref.alpha[moving]), ref.dq_d[moving, 1] / speed[moving], atol=1e-12)


@pytest.mark.parametrize("name", PATHS)
def test_tangent_angle_is_defined_at_rest(name: str) -> None:
    path, rate = PATHS[name]
    ref = reference(path, TimingLaw(rate, "rest"), np.array([0.0]))
    np.testing.assert_allclose(ref.dq_d, 0.0)
    assert ref.alpha[0] == pytest.approx(0.0)  # both curves start at the bottom moving +x
    assert ref.dalpha[0] == 0.0 and ref.ddalpha[0] == 0.0


@pytest.mark.parametrize("start", ["on_path", "rest"])
def test_contour_speeds_after_the_ramp(start: str) -> None:
    t = np.linspace(0.6, 10.0, 2001)
    circle_ref = reference(circle(), TimingLaw(2.0, start), t)
    np.testing.assert_allclose(np.linalg.norm(circle_ref.dq_d, axis=1), 0.4, rtol=1e-12)
    timing = TimingLaw(3.0, start)
    ellipse_ref = reference(paper_ellipse(), timing, t)
    # The formula (docs/equations.md, timing law) is in the time of the on_path law; the rest law lags it by
    # half a ramp.
    t_on_path = t - (0.5 * timing.ramp_s if start == "rest" else 0.0)
    expected = 0.3 * np.sqrt(1.0 + 3.0 * np.cos(3.0 * t_on_path) ** 2)
    np.testing.assert_allclose(np.linalg.norm(ellipse_ref.dq_d, axis=1), expected, rtol=1e-12)


def test_paper_ellipse_geometry() -> None:
    phi = np.linspace(0.0, 2 * np.pi, 9)
    p = paper_ellipse().derivatives(phi)[0]
    np.testing.assert_allclose(p[:, 0], 0.2 * np.sin(phi), atol=1e-15)
    np.testing.assert_allclose(p[:, 1], -0.1 * np.cos(phi) + 0.1, atol=1e-15)
    assert circle().period_rad == pytest.approx(2 * math.pi)


# ---- the true contouring error eps_c -----------------------------------------------------


def brute_force_distance(path, q: np.ndarray, samples: int = 4001, rounds: int = 6) -> np.ndarray:
    """Distance from each point to the whole curve: global grid, then zooming grids (metres)."""
    out = np.empty(len(q))
    for i, point in enumerate(q):
        lo, hi = 0.0, path.period_rad
        for _ in range(rounds):
            phi = np.linspace(lo, hi, samples)
            d = np.linalg.norm(path.derivatives(phi)[0] - point, axis=1)
            k = int(np.argmin(d))
            step = (hi - lo) / (samples - 1)
            lo, hi = phi[k] - 2 * step, phi[k] + 2 * step
        out[i] = d[k]
    return out


@pytest.mark.parametrize("name", PATHS)
def test_contour_error_is_the_distance_to_the_curve(name: str) -> None:
    path, rate = PATHS[name]
    rng = np.random.default_rng(RNG_SEED)
    t = rng.uniform(0.0, 5.0, 60)
    ref = reference(path, TimingLaw(rate), t)
    # Offsets from 1 um to 5 mm in random directions, and desired phi a little off the closest point.
    direction = rng.normal(size=(t.size, 2))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    size = 10.0 ** rng.uniform(-6, np.log10(5e-3), t.size)
    q = ref.q_d + size[:, None] * direction
    eps_c, phi_star = contour_error(path, q, ref.phi)
    np.testing.assert_allclose(np.abs(eps_c), brute_force_distance(path, q), rtol=1e-6, atol=1e-10)
    # The closest point is where the offset is normal to the curve.
    p, dp, _, _ = path.derivatives(phi_star)
    np.testing.assert_allclose(np.einsum("ij,ij->i", q - p, dp), 0.0, atol=1e-12)
    # Signed like eps_n: positive on the left of the direction of travel.
    alpha = np.arctan2(dp[:, 1], dp[:, 0])
    side = -np.sin(alpha) * (q - p)[:, 0] + np.cos(alpha) * (q - p)[:, 1]
    assert np.all(np.sign(eps_c) == np.sign(side))


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"rate_rad_s": 0.0}, "timing.rate_rad_s"),
        ({"rate_rad_s": float("nan")}, "timing.rate_rad_s"),
        ({"rate_rad_s": 2.0, "start": "rest", "ramp_s": 0.0}, "timing.ramp_s"),
        ({"rate_rad_s": 2.0, "start": "sideways"}, "timing.start"),
    ],
)
def test_timing_law_rejects_bad_settings(kwargs, field):
    with pytest.raises(ValueError, match=field):
        TimingLaw(**kwargs)


@pytest.mark.parametrize("path", [circle(), paper_ellipse()], ids=["circle", "ellipse"])
@pytest.mark.parametrize("start", ["on_path", "rest"])
def test_reference_in_pieces_is_the_reference_of_the_whole(path, start):
    """ReferenceStream over pieces of 1 s (and one of 1 sample) of a 20 s run: every array bit for bit as one call,
    alpha unwrapped across the seams (it wraps every lap) as np.unwrap does over the whole."""
    ts, n = 2e-4, 100_000
    timing = TimingLaw(3.0, start=start)
    t = np.arange(n) * ts
    whole = reference(path, timing, t)
    raw_alpha = tangent_angle(path, timing.derivatives(t)[0])[0]
    np.testing.assert_array_equal(whole.alpha, np.unwrap(raw_alpha))
    assert whole.alpha[-1] - whole.alpha[0] > 8 * np.pi  # several laps: several wraps
    stream = ReferenceStream(path, timing)
    seams = [0, 1, *range(5000, n, 5000), n]
    pieces = [stream.next(t[a:b]) for a, b in zip(seams[:-1], seams[1:], strict=True)]
    for field in ("t_s", "phi", "dphi", "q_d", "dq_d", "ddq_d", "alpha", "dalpha", "ddalpha"):
        joined = np.concatenate([getattr(piece, field) for piece in pieces])
        np.testing.assert_array_equal(joined, getattr(whole, field), err_msg=field)
