"""Sweep axes name their unit, taken from the field or metric name (gantry_twin.sweep.plots.unit_of)."""

from __future__ import annotations

import pytest

from gantry_twin.sweep.plots import axis_label, unit_of


@pytest.mark.parametrize(
    ("name", "unit"),
    [
        ("payload.mass_kg", "kg"),
        ("contour.timing.rate_rad_s", "rad/s"),
        ("contour.radius_m", "m"),
        ("contour_rms_um", "µm"),
        ("duration_s", "s"),
        ("controller.options.gains.ks_v_s_m", "V/(m/s)"),
        ("plant.friction.x.sigma0_n_m", "N/m"),
        ("plant.friction.x.vs_m_s", "m/s"),
        ("estimate_M1", "V s²/m"),
        ("estimate_Af2", "V"),
        ("true_B1", "V s/m"),
        ("error_pct_M1", "%"),
        ("error_pct_dN2", "%"),
        ("changes.cogging.0.amplitude_v", "V"),
        ("controller.name", ""),
        ("monitor.tolerance_pct", "%"),
    ],
)
def test_the_unit_comes_from_the_name(name, unit):
    assert unit_of(name) == unit
    assert axis_label(name) == (f"{name} ({unit})" if unit else name)
