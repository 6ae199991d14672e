"""Ranges declared once, on the settings types: the same check and text from Python and from a scenario file."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest

from gantry_twin.controllers import DARC, DIARC, DRC, PD, ArcGains, EstimatorSettings, register, unregister
from gantry_twin.health.monitor import ExcitationSettings, HealthSettings
from gantry_twin.numerics.estimation import LeastSquaresSettings
from gantry_twin.plant.faults import CoggingRipple, EncoderGlitch, FrictionDrift, PayloadChange, VelocityNoise
from gantry_twin.plant.model import Payload
from gantry_twin.plant.sensing import SensingConfig
from gantry_twin.scenario import ScenarioError, validate_data
from gantry_twin.scenario.schema import typed_options
from gantry_twin.settings import QUOTE_MAX_CHARS, Count, Range, Vector, quote, validated


@validated("thing")
class Thing:
    """A settings type of every kind of field, for the tests."""

    length_m: Range(0.0, 2.0, "m", lo_open=True) = 1.0
    count: Count(1, 5) = 1
    pair: Vector(Range(-1.0, 1.0, "V"), ("x", "y")) = (0.0, 0.0)


@pytest.mark.parametrize(
    ("kwargs", "text"),
    [
        ({"length_m": 0.0}, "thing.length_m: must be in (0, 2] m, got 0.0"),
        ({"length_m": 2.5}, "thing.length_m: must be in (0, 2] m, got 2.5"),
        ({"length_m": math.nan}, "thing.length_m: must be in (0, 2] m, got nan"),
        ({"length_m": math.inf}, "thing.length_m: must be in (0, 2] m, got inf"),
        ({"length_m": True}, "thing.length_m: must be a number, not a boolean; allowed: (0, 2] m"),
        ({"length_m": "1"}, "thing.length_m: must be a valid number in (0, 2] m, got '1'"),
        ({"count": 0}, "thing.count: must be an integer in [1, 5], got 0"),
        ({"count": 2.5}, "thing.count: must be a valid integer in [1, 5], got 2.5"),
        ({"pair": (0.0, 1.5)}, "thing.pair.y: must be in [-1, 1] V, got 1.5"),
        ({"pair": (0.0,)}, "thing.pair: too few items: must be two numbers (x, y), got 1"),
        ({"pair": (0.0, 0.0, 0.0)}, "thing.pair: too many items: must be two numbers (x, y), got 3"),
        ({"pair": "ab"}, "thing.pair: must be two numbers (x, y), got 'ab'"),
        ({"size": 3}, "thing.size: unknown key; allowed: length_m, count, pair"),
    ],
)
def test_python_errors_are_one_line_naming_field_and_range(kwargs, text):
    with pytest.raises(ValueError) as info:
        Thing(**kwargs)
    assert str(info.value) == text


def test_positional_arguments_are_named_in_errors():
    with pytest.raises(ValueError, match=r"^thing\.count: "):
        Thing(1.0, 9)


def test_values_are_converted_and_the_bounds_included():
    t = Thing(np.float64(2.0), np.int64(5), np.array([-1.0, 1.0]))
    assert (t.length_m, t.count, t.pair) == (2.0, 5, (-1.0, 1.0))
    assert type(t.length_m) is float and type(t.count) is int and type(t.pair) is tuple
    assert Thing(count=3.0).count == 3


def test_settings_are_frozen_and_compare_by_value():
    a, b = Thing(), Thing(1.0, 1, (0.0, 0.0))
    assert a == b and hash(a) == hash(b)
    with pytest.raises(AttributeError):
        a.length_m = 2.0  # type: ignore[misc]


# Each settings type of the twin, a bad value for one of its fields, and the field its error must name.
BAD_PYTHON_VALUES = [
    (lambda: Payload(mass_kg=-1.0), "payload.mass_kg: must be in [0, 20] kg"),
    (lambda: SensingConfig(resolution_m=0.5), "sensing.resolution_m: must be in [1e-09, 0.001] m"),
    (lambda: ArcGains(ks_v_s_m=(100.0, 0.0)), "gains.ks_v_s_m.tangential: must be in [1, 1000] V/(m/s)"),
    (lambda: ArcGains(theta_min=(1.0,) * 8), "gains.theta_max: need theta_min <= theta_max"),
    (lambda: EstimatorSettings(filter_hz=(0.0, 50.0)), "estimator.filter_hz.x: must be in [5, 500] Hz"),
    (lambda: EstimatorSettings(least_squares={"kappa": -1}), "estimator.least_squares.kappa: must be in [0, 100] 1/s"),
    (lambda: LeastSquaresSettings(rho_max=0.0), "least_squares.rho_max: must be in (0, 1e+08]"),
    (lambda: FrictionDrift("y", 0.0, 1.0, coulomb_to_v=6.0), "friction_drift.coulomb_to_v: must be in [0, 5] V"),
    (lambda: PayloadChange(1.0, 25.0), "payload_change.mass_kg: must be in [0, 20] kg"),
    (lambda: CoggingRipple("x", 0.05, 0.016, phase_rad=7.0), "cogging.phase_rad: must be in [-6.28319, 6.28319]"),
    (lambda: EncoderGlitch("spike", 2e6), "encoder_glitch.time_s: must be in [0, 1e+06] s"),
    (lambda: VelocityNoise((0.01, 0.01), start_s=2.0, end_s=1.0), "velocity_noise.end_s: must be after start_s"),
    (lambda: ExcitationSettings(min_moving_fraction=1.5), "excitation.min_moving_fraction: must be in [0, 1]"),
    (lambda: HealthSettings(decision_interval_s=0.0), "health.decision_interval_s: must be in (0, 100] s"),
]


@pytest.mark.parametrize(("build", "start"), BAD_PYTHON_VALUES, ids=[b[1].split(":")[0] for b in BAD_PYTHON_VALUES])
def test_every_settings_type_rejects_a_bad_value_in_one_line(build, start):
    with pytest.raises(ValueError) as info:
        build()
    assert str(info.value).startswith(start), str(info.value)
    assert "\n" not in str(info.value)


# The same setting given in a scenario file and from Python: one declaration, one message.
SAME_SETTING = [
    ({"payload": {"mass_kg": 21}}, "payload.mass_kg", lambda: Payload(21)),
    ({"sensing": {"resolution_m": 0.0}}, "sensing.resolution_m", lambda: SensingConfig(resolution_m=0.0)),
    (
        {"changes": {"cogging": [{"axis": "x", "amplitude_v": 3, "pitch_m": 0.016}]}},
        "changes.cogging[0].amplitude_v",
        lambda: CoggingRipple("x", 3, 0.016),
    ),
    (
        {"controller": {"name": "diarc", "options": {"estimator": {"settle_s": -1}}}},
        "controller.options.estimator.settle_s",
        lambda: EstimatorSettings(settle_s=-1),
    ),
    (
        {"controller": {"name": "darc", "options": {"gains": {"friction_slope_s_m": 0}}}},
        "controller.options.gains.friction_slope_s_m",
        lambda: ArcGains(friction_slope_s_m=0),
    ),
    (
        {"monitor": {"decision_interval_s": 200}},
        "monitor.decision_interval_s",
        lambda: HealthSettings(decision_interval_s=200),
    ),
]


@pytest.mark.parametrize(("data", "field", "python"), SAME_SETTING, ids=[s[1] for s in SAME_SETTING])
def test_a_scenario_and_python_say_the_same_about_a_setting(data, field, python):
    with pytest.raises(ScenarioError) as from_file:
        validate_data(data, "f.yaml")
    with pytest.raises(ValueError) as from_python:
        python()
    assert from_file.value.field == field
    assert from_file.value.message == str(from_python.value).partition(": ")[2]


@pytest.mark.parametrize("factory", [DRC, DARC, DIARC, PD])
def test_builtin_options_are_the_constructor_arguments(factory):
    options = typed_options(factory)
    import inspect

    assert list(options.model_fields) == list(inspect.signature(factory).parameters)


def test_pd_options_default_to_the_pd_fields():
    defaults = {name: f.default for name, f in typed_options(PD).model_fields.items()}
    assert defaults == {name: getattr(PD(), name) for name in defaults}


def test_plugin_options_are_not_typed():
    class Plugin:
        def __init__(self, gain: float = 1.0) -> None:
            self.gain = gain

    register("test_ranges_plugin", Plugin)
    try:
        assert typed_options(Plugin) is None
    finally:
        unregister("test_ranges_plugin")


# ---------------------------------------------------------------------------
# Physically meaningful bounds on the estimator and controller settings, each documented.

DOCS = Path(__file__).resolve().parents[1] / "docs" / "scenarios.md"

#: (field path in a scenario, controller, just below the lower bound, the bounds, just above the upper bound).
BOUNDED = [
    ("controller.options.estimator.filter_hz", "diarc", (4.99, 5.0, 500.0, 500.1), "[5, 500] Hz"),
    ("controller.options.estimator.filter_zeta", "diarc", (0.099, 0.1, 5.0, 5.01), "[0.1, 5]"),
    ("controller.options.estimator.least_squares.nu", "diarc", (-1e-9, 0.0, 1.0, 1.01), "[0, 1]"),
    ("controller.options.estimator.least_squares.kappa", "diarc", (-1e-9, 0.0, 100.0, 100.1), "[0, 100] 1/s"),
    ("controller.options.estimator.least_squares.rho_max", "diarc", (0.0, 1e-9, 1e8, 1.01e8), "(0, 1e+08]"),
    ("controller.options.estimator.least_squares.gamma0_diag", "diarc", (0.099, 0.1, 1e8, 1.01e8), "[0.1, 1e+08]"),
    ("controller.options.estimator.gamma_d", "diarc", (-1e-9, 0.0, 1e6, 1.01e6), "[0, 1e+06]"),
    ("controller.options.estimator.dc_max_v", "diarc", (-1e-9, 0.0, 10.0, 10.01), "[0, 10] V"),
    ("controller.options.estimator.settle_s", "diarc", (-1e-9, 0.0, 10.0, 10.01), "[0, 10] s"),
    ("controller.options.gains.lambda_1_s", "drc", (0.99, 1.0, 5000.0, 5001.0), "[1, 5000] 1/s"),
    ("controller.options.gains.ks_v_s_m", "darc", (0.99, 1.0, 1000.0, 1001.0), "[1, 1000] V/(m/s)"),
    ("controller.options.gains.friction_slope_s_m", "diarc", (99.0, 100.0, 1e6, 1.01e6), "[100, 1e+06] s/m"),
    ("controller.options.gamma", "darc", (-1e-9, 0.0, 1e8, 1.01e8), "[0, 1e+08]"),
    ("controller.options.kp_v_m", "pd", (-1e-9, 0.0, 1e5, 1.01e5), "[0, 100000] V/m"),
    ("controller.options.kd_v_s_m", "pd", (-1e-9, 0.0, 1000.0, 1001.0), "[0, 1000] V/(m/s)"),
    ("controller.options.kv_v_s_m", "pd", (-1e-9, 0.0, 10.0, 10.01), "[0, 10] V/(m/s)"),
    ("controller.options.ka_v_s2_m", "pd", (-1e-9, 0.0, 2.0, 2.01), "[0, 2] V/(m/s^2)"),
    ("sensing.resolution_m", "diarc", (0.99e-9, 1e-9, 1e-3, 1.01e-3), "[1e-09, 0.001] m"),
    ("monitor.filter_hz", "diarc", (4.99, 5.0, 500.0, 500.1), "[5, 500] Hz"),
]
#: How many numbers each vector field takes (the others take one).
VECTOR_SIZE = {"filter_hz": 2, "gamma0_diag": 8, "gamma_d": 2, "dc_max_v": 2, "lambda_1_s": 2, "ks_v_s_m": 2}
VECTOR_SIZE |= {"gamma": 8, "kp_v_m": 2, "kd_v_s_m": 2, "kv_v_s_m": 2, "ka_v_s2_m": 2}


def _scenario(path: str, controller: str, value: float) -> dict:
    leaf = path.rsplit(".", 1)[1]
    data: dict = {"controller": {"name": controller}}
    node = data
    for part in path.split(".")[:-1]:
        node = node.setdefault(part, {})
    n = VECTOR_SIZE.get(leaf)
    node[leaf] = [value] * n if n else value
    return data


@pytest.mark.parametrize(("path", "controller", "values", "allowed"), BOUNDED, ids=[b[0] for b in BOUNDED])
def test_settings_have_physical_bounds_stated_and_documented(path, controller, values, allowed):
    below, lo, hi, above = values
    for inside in (lo, hi):
        validate_data(_scenario(path, controller, inside), "f.yaml")
    for outside in (below, above):
        with pytest.raises(ScenarioError) as info:
            validate_data(_scenario(path, controller, outside), "f.yaml")
        assert info.value.field.startswith(path)
        assert f"must be in {allowed}, got" in info.value.message
    leaf = path.rsplit(".", 1)[1]
    rows = [line for line in DOCS.read_text().split("## Why these ranges")[1].splitlines() if f"`{leaf}`" in line]
    assert any(f"| {allowed} |" in row for row in rows), f"docs/scenarios.md: no row for `{leaf}` with {allowed}"


def test_a_vanishing_filter_frequency_is_refused_from_python_and_from_a_scenario():
    """``estimator.filter_hz=[1e-300, 50]`` was once accepted and froze the X estimates at theta0."""
    with pytest.raises(ValueError, match=r"^estimator\.filter_hz\.x: must be in \[5, 500\] Hz, got 1e-300$"):
        EstimatorSettings(filter_hz=(1e-300, 50.0))
    with pytest.raises(ScenarioError, match=r"filter_hz\[0\]: must be in \[5, 500\] Hz"):
        validate_data(_scenario("controller.options.estimator.filter_hz", "diarc", 1e-300), "f.yaml")


def test_the_named_estimators_and_default_gains_are_inside_the_ranges():
    from dataclasses import asdict

    from gantry_twin.controllers.estimator import NAMED_ESTIMATORS

    for named in NAMED_ESTIMATORS.values():
        assert EstimatorSettings(**asdict(named)) == named
    assert ArcGains(**asdict(ArcGains())) == ArcGains()


# ---------------------------------------------------------------------------
# Every value a message quotes is cut short, however big or deep it is.


def _bomb(levels: int = 9) -> list:
    value: list = list(range(9))
    for _ in range(levels):
        value = [value] * 9  # nine references to one list: 9**10 numbers if expanded
    return value


@pytest.mark.parametrize(
    "value", ["x" * 1_000_000, _bomb(), 7**4000, {"k" * 100_000: 1}, b"\x00" * 100_000, (1.5,) * 10_000]
)
def test_quote_is_short_and_quick(value):
    # CPU time, not wall time: the bound is on the work done, which a loaded machine does not change.
    started = time.process_time()
    text = quote(value)
    assert len(text) <= QUOTE_MAX_CHARS
    assert time.process_time() - started < 0.1


@pytest.mark.parametrize(
    "data",
    [
        {"x" * 1_000_000: 1},
        {"duration_s": "x" * 1_000_000},
        {"window_s": _bomb()},
        {"name": "n" * 1_000_000},
        {"controller": {"name": "c" * 1_000_000}},
        {"contour": {"type": "s" * 1_000_000}},
        {"payload": {"mass_kg": [1] * 1_000_000}},
        {"contour": {"timing": {"start": "s" * 1_000_000}}},
        {"controller": {"name": "diarc", "options": {"o" * 1_000_000: 1}}},
    ],
)
def test_every_message_quotes_a_big_value_short(data):
    # CPU time (see test_quote_is_short_and_quick).
    started = time.process_time()
    with pytest.raises(ScenarioError) as info:
        validate_data(data, "f.yaml")
    assert len(str(info.value)) < 300, str(info.value)[:500]
    assert time.process_time() - started < 1.0
