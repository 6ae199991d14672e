"""The controller plug-in interface and the loop's safety checks."""

from __future__ import annotations

import sys
import textwrap

import numpy as np
import pytest

from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import DIARC, available, create, register, unregister
from gantry_twin.controllers.base import Measurement, ReferenceSample, RunContext
from gantry_twin.loop.trace import SimulationError

from .helpers import run


class ToyController:
    """Per-axis P + velocity feed-forward, defined here, outside the package."""

    def __init__(self, kp_v_m: float = 3000.0) -> None:
        self.kp_v_m = kp_v_m
        self.samples = 0

    def reset(self, context: RunContext) -> None:
        self.samples = 0
        self.ts = context.sample_period_s

    def update(self, measurement: Measurement, reference: ReferenceSample) -> np.ndarray:
        self.samples += 1
        return -self.kp_v_m * (measurement.q_m - reference.q_d) + 0.6 * reference.dq_d

    def state_for_logging(self) -> dict[str, np.ndarray]:
        return {"samples": np.array([float(self.samples)])}


@pytest.fixture
def toy_registered():
    register("toy", ToyController)
    yield
    unregister("toy")


def test_builtins_are_registered():
    assert {"diarc", "darc", "drc", "pd"} <= set(available())


def test_toy_controller_runs_the_loop_without_package_changes(toy_registered):
    controller = create("toy", kp_v_m=2000.0)
    trace = simulate(Plant(), circle(), TimingLaw(2.0), controller, 0.5)
    n = trace.t_s.size
    assert controller.samples == n
    np.testing.assert_array_equal(trace.controller_state["samples"], np.arange(1, n + 1))
    # A P controller with 2000 V/m on a 0.4 m/s circle lags by millimetres, but it tracks.
    assert np.abs(trace.e_m).max() < 5e-3


def test_controller_from_an_installed_package_entry_point(tmp_path, monkeypatch):
    """A controller shipped by another package is found through the entry-point group."""
    pkg = tmp_path / "acme_ctrl"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(
        textwrap.dedent("""
        import numpy as np
        class Zero:
            def reset(self, context): pass
            def update(self, measurement, reference): return np.zeros(2)
            def state_for_logging(self): return {}
    """)
    )
    dist = tmp_path / "acme_ctrl-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: acme-ctrl\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[gantry_twin.controllers]\nacme_zero = acme_ctrl:Zero\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert "acme_zero" in available()
    controller = create("acme_zero")
    trace = simulate(Plant(), circle(), TimingLaw(2.0), controller, 0.01)
    np.testing.assert_array_equal(trace.u_v, 0.0)
    sys.modules.pop("acme_ctrl", None)


def test_unknown_controller_names_the_choices():
    with pytest.raises(KeyError, match="available: .*diarc"):
        create("no_such_controller")


class Shouting(ToyController):
    def update(self, measurement, reference):
        return np.array([50.0, -80.0])


def test_commands_are_clipped_to_the_dac_range():
    trace = simulate(Plant(), circle(), TimingLaw(2.0), Shouting(), 0.05)
    np.testing.assert_array_equal(trace.u_v, np.tile([10.0, -10.0], (trace.t_s.size, 1)))


class BadCommand(ToyController):
    def update(self, measurement, reference):
        return np.array([np.nan, 0.0]) if measurement.t_s > 0.01 else np.zeros(2)


def test_non_finite_command_stops_the_run():
    with pytest.raises(SimulationError, match="controller returned"):
        simulate(Plant(), circle(), TimingLaw(2.0), BadCommand(), 0.1)


class Sabotage:
    """An observer that corrupts the plant state (only tests do this)."""

    def __init__(self, plant):
        self.plant = plant

    def on_start(self, run, trace):
        pass

    def on_chunk(self, trace, start, stop):
        self.plant.data.qpos[:] = np.nan

    def on_end(self, trace):
        pass


@pytest.mark.parametrize("controller", ["diarc", "pd"])
def test_non_finite_measurement_stops_the_run(controller):
    plant = Plant()
    with pytest.raises(SimulationError, match="non-finite measurement"):
        simulate(plant, circle(), TimingLaw(2.0), create(controller), 0.5, observers=[Sabotage(plant)], chunk_s=0.1)


class GammaSampler:
    """Observer keeping DIARC's full Gamma (8 x 8) and the sample it belongs to, after every chunk."""

    def __init__(self, controller: DIARC) -> None:
        self.controller = controller
        self.samples: list[int] = []
        self.gammas: list[np.ndarray] = []

    def on_start(self, run, trace):  # noqa: ANN001, ANN201
        pass

    def on_chunk(self, trace, start, stop):  # noqa: ANN001, ANN201
        self.samples.append(stop - 1)
        self.gammas.append(self.controller.estimator.gamma.copy())

    def on_end(self, trace):  # noqa: ANN001, ANN201
        pass


@pytest.mark.slow
def test_gamma_stays_spd_and_bounded_through_20_s():
    """The full Gamma, sampled every 0.1 s of a 20 s circle run, is symmetric positive definite and
    bounded (docs/equations.md, the estimator's least squares); the logged lambda_max and diagonal are those
    of that matrix."""
    controller = DIARC()
    sampler = GammaSampler(controller)
    trace, _ = run("diarc", duration_s=20.0, observers=[sampler], controller=controller)
    gammas = np.array(sampler.gammas)
    assert gammas.shape == (200, 8, 8)
    assert np.abs(gammas[-1] - gammas[0]).max() > 1.0  # the samples follow the run (not a stale copy)
    np.testing.assert_array_equal(gammas[-1], controller.estimator.gamma)  # the last one is the final Gamma
    np.testing.assert_array_equal(gammas, gammas.transpose(0, 2, 1))
    eigenvalues = np.linalg.eigvalsh(gammas)  # ascending, per sample
    assert np.all(eigenvalues[:, 0] > 0.0), f"smallest eigenvalue {eigenvalues[:, 0].min():.3g}"
    # Gamma(0) = diag(10, ..., 5000, 5000): the information term only shrinks Gamma, and forgetting
    # grows it only while lambda_max <= rho_M = 500 (by exp(kappa Ts) per sample at most).
    ts = trace.sample_period_s
    assert eigenvalues[:, -1].max() <= 5000.0 * (1 + 1e-9)
    assert eigenvalues[-1, -1] <= 500.0 * np.exp(0.1 * ts) * (1 + 1e-9)
    logged = trace.controller_state
    np.testing.assert_allclose(logged["gamma_lambda_max"][sampler.samples], eigenvalues[:, -1], rtol=1e-9)
    np.testing.assert_array_equal(logged["gamma_diag"][sampler.samples], np.diagonal(gammas, axis1=1, axis2=2))
