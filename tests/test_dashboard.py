"""The dashboard's layout: every plot titled with its unit, estimate plots ranged to show the truth, labelled ticks."""

from __future__ import annotations

import math

import numpy as np
import pytest
import rerun as rr
import rerun.blueprint as rrb
from hypothesis import given
from hypothesis import strategies as st

from gantry_twin import Plant, TimingLaw, circle, create, simulate
from gantry_twin.plant.faults import PayloadChange, PlantChanges
from gantry_twin.plant.model import THETA_NAMES
from gantry_twin.telemetry import RerunObserver, theta_entity
from gantry_twin.telemetry.dashboard import RANGE_MARGIN, RANGE_MAX_LABELS, plot_range


def _labelled_ticks(a: float, b: float, step: float) -> int:
    """Multiples of ``step`` at least step / 10 inside [a, b] (the viewer drops a label at the very edge)."""
    inner = step / 10 * 0.99  # less 1 % for rounding
    return math.floor((b - inner) / step) - math.ceil((a + inner) / step) + 1


@given(
    st.floats(-1e4, 1e4, allow_nan=False),
    st.floats(0.0, 1e4, allow_nan=False).filter(lambda s: s == 0 or s > 1e-6),
)
def test_a_plot_range_shows_the_data_with_a_margin_and_two_labelled_ticks(lo, span):
    hi = lo + span
    a, b = plot_range(lo, hi)
    margin = RANGE_MARGIN * span * (1 - 1e-9)
    assert a <= lo - margin and b >= hi + margin
    decades = [10.0**k for k in range(math.floor(math.log10(b - a)) - 2, math.floor(math.log10(b - a)) + 2)]
    assert any(2 <= _labelled_ticks(a, b, d) <= RANGE_MAX_LABELS for d in decades), (a, b)
    assert span == 0 or b - a <= 6 * span  # not so wide that the data is a flat line


def _views(container) -> list:
    found = []
    for child in getattr(container, "contents", None) or []:
        found += [child] if hasattr(child, "origin") else _views(child)
    return found


def _range(view) -> tuple[float, float] | None:
    axis = (view.properties or {}).get("ScalarAxis")
    if axis is None or axis.range is None:
        return None
    (lo, hi) = axis.range.as_arrow_array().to_pylist()[0]
    return lo, hi


@pytest.fixture(scope="module")
def pickup_run():
    """DIARC through a 5 kg pick-up at 0.5 s (the truth moves), with every blueprint the observer sent."""
    recording = rr.RecordingStream("test_dashboard")
    recording.memory_recording()
    sent: list[rrb.Blueprint] = []
    send = recording.send_blueprint
    recording.send_blueprint = lambda blueprint, **kwargs: (sent.append(blueprint), send(blueprint, **kwargs))
    changes = PlantChanges(payload_change=(PayloadChange(time_s=0.5, mass_kg=5.0),))
    observer = RerunObserver(recording)
    trace = simulate(
        Plant(payload_body=True), circle(), TimingLaw(2.0), create("diarc"), 1.0, observers=[observer], changes=changes
    )
    return trace, sent


def test_every_plot_is_titled_with_its_unit(pickup_run):
    _, sent = pickup_run
    views = _views(sent[-1].root_container)
    assert len(views) >= 14
    for view in views:
        assert "[" in str(view.name) and str(view.name).split("[", 1)[1].split("]")[0], view.name


def test_estimate_plots_show_the_truth_and_the_estimate_with_a_margin(pickup_run):
    trace, sent = pickup_run
    ranges = {str(v.origin): _range(v) for v in _views(sent[-1].root_container)}
    truth, theta = trace.true_parameters_t(), trace.controller_state["theta_hat"]
    assert truth[0, 0] < truth[-1, 0]  # the pick-up moved M1's truth
    for i, name in enumerate(THETA_NAMES):
        lo, hi = ranges[theta_entity(name)]
        shown = np.concatenate([truth[:, i], theta[:, i]])
        margin = RANGE_MARGIN * (shown.max() - shown.min()) * (1 - 1e-9)
        assert lo <= shown.min() - margin and shown.max() + margin <= hi, (name, lo, hi)
    dc = trace.controller_state["dc_hat"]
    lo, hi = ranges["estimates/dc_hat_V"]
    assert lo < dc.min() and dc.max() < hi
    lo, hi = ranges["inputs"]
    assert lo < trace.u_v.min() and trace.u_v.max() < hi


def test_error_plots_are_in_micrometres_and_ranged_to_every_sample(pickup_run):
    # The viewer's own range for the axial errors labelled a single "0" tick (a 4 s rig-plant run).
    trace, sent = pickup_run
    views = {str(v.origin): v for v in _views(sent[-1].root_container)}
    for origin, values in (
        ("errors/contour", np.concatenate([trace.eps_c_m, trace.eps_n_m]) * 1e6),
        ("errors/axial", trace.e_m * 1e6),
    ):
        assert str(views[origin].name).endswith("[µm]"), views[origin].name
        lo, hi = _range(views[origin])
        assert lo < values.min() and values.max() < hi, origin


def test_the_layout_is_sent_again_only_when_data_leaves_a_plot(pickup_run):
    _, sent = pickup_run
    assert 1 <= len(sent) <= 12  # 10 chunks of 0.1 s; not one layout per chunk
