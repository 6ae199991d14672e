"""Ranges declared once, on the settings types: the same check and text from Python and from a scenario file."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gantry_twin.changes import CoggingRipple, EncoderGlitch, FrictionDrift, PayloadChange, VelocityNoise
from gantry_twin.controllers import DARC, DIARC, DRC, PD, ArcGains, EstimatorSettings, register, unregister
from gantry_twin.estimation import LeastSquaresSettings
from gantry_twin.monitor import ExcitationSettings, HealthSettings
from gantry_twin.plant import Payload
from gantry_twin.ranges import Count, Range, Vector, settings
from gantry_twin.scenario import ScenarioError, validate_data
from gantry_twin.scenario.schema import typed_options
from gantry_twin.sensing import SensingConfig


@settings("thing")
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
