"""The identification trajectory and ``gantry-twin excite`` (docs/logs.md)."""

from __future__ import annotations

import numpy as np
import pyarrow.csv as pacsv
import pytest

from gantry_twin.cli import main
from gantry_twin.sysid.logs import read_log
from gantry_twin.sysid.trajectory import (
    COMMAND_BUDGET_V,
    PLATEAU_COUNT,
    PLATEAU_HOLD_S,
    PLATEAU_SPEEDS_M_S,
    POSITION_LIMIT_M,
    SPEED_LIMIT_M_S,
    budget_theta,
    design,
    with_plateaus,
)


@pytest.mark.parametrize("duration_s, plateaus", [(8.0, False), (20.0, False), (20.0, True)])
def test_trajectory_within_travel_speed_and_volts_and_at_rest_at_both_ends(duration_s, plateaus):
    path = with_plateaus(design(duration_s)) if plateaus else design(duration_s)
    duration_s = path.duration_s if plateaus else duration_s
    t = np.arange(0.0, duration_s + 1e-9, 2e-4)
    p, dp, ddp, _ = path.derivatives(t)
    theta = budget_theta()
    volts = theta[0:2] * np.abs(ddp) + theta[2:4] * np.abs(dp) + theta[4:6] * (np.abs(dp) > 0)
    assert np.abs(p).max() <= POSITION_LIMIT_M * 1.01
    assert np.abs(dp).max() <= SPEED_LIMIT_M_S * 1.01
    assert volts.max() <= COMMAND_BUDGET_V * 1.01
    for end in (0, -1):
        np.testing.assert_allclose([p[end], dp[end], ddp[end]], 0.0, atol=1e-12)
    # Both axes move both ways at many speeds: what separates B from Af.
    for axis in range(2):
        assert np.abs(p[:, axis]).max() > 0.05 and (dp[:, axis] > 0.2).any() and (dp[:, axis] < -0.2).any()


@pytest.mark.parametrize("plateaus", [False, True])
def test_derivatives_are_those_of_the_position(plateaus):
    path = with_plateaus(design(8.0)) if plateaus else design(8.0)
    t = np.linspace(0.3, path.duration_s - 0.3, 4001)
    h = 1e-5
    p, dp, ddp, dddp = path.derivatives(t)
    plus, minus = path.derivatives(t + h), path.derivatives(t - h)
    for lower, higher in ((0, dp), (1, ddp), (2, dddp)):
        numeric = (plus[lower] - minus[lower]) / (2 * h)
        np.testing.assert_allclose(higher, numeric, rtol=0, atol=1e-5 * np.abs(higher).max())


def test_plateaus_hold_each_speed_both_ways():
    """After the multisine every speed of PLATEAU_SPEEDS_M_S is held for PLATEAU_HOLD_S, both ways, both axes."""
    path = with_plateaus(design(8.0))
    t = np.arange(8.0, path.duration_s, 1e-3)
    _, dp, _, _ = path.derivatives(t)
    speeds = np.geomspace(*PLATEAU_SPEEDS_M_S, PLATEAU_COUNT)
    for axis in range(2):
        for v in np.concatenate([speeds, -speeds]):
            held = np.abs(dp[:, axis] - v) < 1e-12 * abs(v)
            assert held.sum() * 1e-3 == pytest.approx(PLATEAU_HOLD_S, abs=2e-3), v


def test_excite_command_writes_trajectory_and_a_log_of_the_twin(tmp_path):
    out = tmp_path / "excite"
    assert main(["excite", "--out", str(out), "--duration-s", "4"]) == 0
    trajectory = pacsv.read_csv(out / "trajectory.csv")
    assert trajectory.column_names[:3] == ["t_s", "x_d_m", "y_d_m"]
    log = read_log(out / "log.parquet")
    assert log.duration_s == pytest.approx(4.0, abs=1e-3)
    assert np.abs(log.q_m - log.q_d_m).max() < 1e-4  # the PD keeps the carriages on the trajectory
    assert np.abs(log.u_v).max() < 10.0  # inside the DAC range: the feedback had headroom


def test_excite_plateaus_flag_appends_them(tmp_path):
    out = tmp_path / "excite"
    assert main(["excite", "--out", str(out), "--duration-s", "4", "--plateaus", "--no-run"]) == 0
    t = pacsv.read_csv(out / "trajectory.csv").column("t_s").to_numpy()
    assert t[-1] == pytest.approx(with_plateaus(design(4.0)).duration_s, abs=1e-3)
    assert not (out / "log.parquet").exists()


def test_excite_bad_duration_exit_2(tmp_path, capsys):
    assert main(["excite", "--out", str(tmp_path / "o"), "--duration-s", "1"]) == 2
    assert "duration_s" in capsys.readouterr().err
