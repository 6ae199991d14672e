"""The plant as an FMU (docs/fmi.md, "The plant as an FMU"): ``gantry-twin fmu export``, native (the default) and
with ``--python`` (pythonfmu), validated by fmpy and driven by a short Python master with fmpy's FMU2Slave around the
built-in ``pd`` law, against ``gantry-twin run``. What only the native FMU does: tests/test_fmi_native.py."""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave
from fmpy.validation import validate_fmu

from gantry_twin.cli import fmu_export
from gantry_twin.cli.common import BadInput
from gantry_twin.controllers.pd import PD
from gantry_twin.fmi.plant import INPUTS, OUTPUTS, CoSimPlant, whole_samples
from gantry_twin.fmi.plant_export import export_plant
from gantry_twin.paths.contours import ReferenceStream
from gantry_twin.plant.model import Plant
from gantry_twin.run import package_version, run_scenario
from gantry_twin.scenario import build, load_scenario, shipped

from .helpers import pushed_from_rest_m

FMI2_ERROR, FMI2_FATAL = 3, 4
DURATION_S = 2.0
TS = 2e-4


@pytest.fixture(scope="module")
def rig_fmu(tmp_path_factory) -> Path:
    """The pythonfmu FMU (``--python``)."""
    return export_plant(tmp_path_factory.mktemp("fmu") / "rig.fmu", python=True).path


@pytest.fixture(scope="module")
def unpacked(rig_fmu, tmp_path_factory) -> Path:
    """The FMU unpacked once for the module (fmpy loads its binary from there); removed after."""
    where = Path(extract(str(rig_fmu), str(tmp_path_factory.mktemp("unpacked"))))
    yield where
    shutil.rmtree(where, ignore_errors=True)


@pytest.fixture(scope="module")
def native_rig(tmp_path_factory) -> tuple[Path, Path]:
    """The native FMU (the default) and where it is unpacked."""
    fmu = export_plant(tmp_path_factory.mktemp("native") / "rig.fmu").path
    where = Path(extract(str(fmu), str(tmp_path_factory.mktemp("native-unpacked"))))
    yield fmu, where
    shutil.rmtree(where, ignore_errors=True)


@pytest.fixture(params=["native", "python"])
def either(request, native_rig, rig_fmu, unpacked) -> tuple[Path, Path]:
    """Each kind of the rig's plant FMU, (fmu, unpacked)."""
    return native_rig if request.param == "native" else (rig_fmu, unpacked)


class Master:
    """The FMU instantiated and initialised by fmpy, its variables by name."""

    def __init__(self, fmu: Path, unpacked: Path, parameters: dict[str, float]) -> None:
        md = read_model_description(str(fmu))
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.slave = FMU2Slave(
            guid=md.guid,
            unzipDirectory=str(unpacked),
            modelIdentifier=md.coSimulation.modelIdentifier,
            instanceName="plant",
        )
        self.slave.instantiate(loggingOn=True)
        try:
            self.slave.setupExperiment(startTime=0.0)
            self.slave.enterInitializationMode()
            self.set(parameters)
            self.slave.exitInitializationMode()
        except FMICallException as exc:
            if exc.status == FMI2_ERROR:  # FMI 2.0 allows fmi2FreeInstance after fmi2Error, not fmi2Terminate
                self.slave.freeInstance()
            elif exc.status != FMI2_FATAL:  # after fmi2Fatal the standard allows no call, not even fmi2FreeInstance
                self.close()
            raise

    def set(self, values: dict[str, float]) -> None:
        self.slave.setReal([self.vr[n] for n in values], list(values.values()))

    def get(self, names) -> np.ndarray:
        return np.array(self.slave.getReal([self.vr[n] for n in names]))

    def close(self) -> None:
        try:
            self.slave.terminate()
        finally:
            self.slave.freeInstance()


def test_either_export_is_a_valid_co_simulation_fmu_with_the_same_variables(native_rig, rig_fmu):
    """The native FMU and the pythonfmu one: valid, and the same variables in the same order with the same value
    references, so that a master that used one needs no change for the other."""
    described = []
    for fmu in (native_rig[0], rig_fmu):
        assert validate_fmu(str(fmu)) == []
        md = read_model_description(str(fmu), validate=True)
        assert md.fmiVersion == "2.0" and md.coSimulation is not None and md.modelExchange is None
        assert md.coSimulation.modelIdentifier == "GantryPlant"
        start = [None if v.start is None else float(v.start) for v in md.modelVariables]
        described.append([(v.name, v.valueReference, v.causality, v.variability) for v in md.modelVariables] + start)
    assert described[0] == described[1]


def test_the_python_export_names_its_python(rig_fmu):
    md = read_model_description(str(rig_fmu), validate=True)
    assert md.fmiVersion == "2.0" and md.coSimulation is not None and md.modelExchange is None
    by_causality = {}
    for v in md.modelVariables:
        by_causality.setdefault(v.causality, []).append(v.name)
    assert by_causality["input"] == list(INPUTS)
    assert by_causality["output"] == list(OUTPUTS)
    assert {"payload.mass_kg", "start.x_m", "friction.x.fc_n", "friction.y.sigma0_n_m"} <= set(
        by_causality["parameter"]
    )
    assert f"gantry-twin {package_version()} installed" in md.description
    names = zipfile.ZipFile(rig_fmu).namelist()
    assert {"resources/models/rig.xml", "resources/models/gantry.xml", "resources/gantry_plant.json"} <= set(names)


def pd_volts(q, dq, q_d, dq_d, ddq_d, gains: PD) -> np.ndarray:
    """The pd law written out here (controllers/pd.py's docstring): u = -kp e - kd e' + kv x_d' + ka x_d'',
    clipped to the DAC's 10 V; the same operations in the same order, so the same doubles."""
    kp, kd, kv, ka = (
        np.asarray(g, dtype=float) for g in (gains.kp_v_m, gains.kd_v_s_m, gains.kv_v_s_m, gains.ka_v_s2_m)
    )
    u = np.zeros(2)
    for i in range(2):
        e, de = q[i] - q_d[i], dq[i] - dq_d[i]
        u[i] = min(max(-kp[i] * e - kd[i] * de + kv[i] * dq_d[i] + ka[i] * ddq_d[i], -10.0), 10.0)
    return u


def test_a_python_master_closing_pd_around_the_fmu_follows_gantry_twin_run(either):
    """2 s of the no-load circle on the rig plant: either FMU's true positions equal the run's to 1e-9 m."""
    rig_fmu, unpacked = either
    overrides = [f"duration_s={DURATION_S}"]
    run = run_scenario("no_load_circle", overrides, controller="pd")
    built = build(load_scenario(shipped("no_load_circle"), overrides, "pd"))
    n = run.trace.t_s.size
    ref = ReferenceStream(built.path, built.timing).next(np.arange(n) * TS)
    start = {"start.x_m": ref.q_d[0, 0], "start.y_m": ref.q_d[0, 1]}
    start |= {"start.dx_m_s": ref.dq_d[0, 0], "start.dy_m_s": ref.dq_d[0, 1]}
    master = Master(rig_fmu, unpacked, start)
    q_true = np.zeros((n, 2))
    try:
        for k in range(n):
            x, y, dx, dy, x_true, y_true = master.get(OUTPUTS[:6])
            q_true[k] = x_true, y_true
            u = pd_volts((x, y), (dx, dy), ref.q_d[k], ref.dq_d[k], ref.ddq_d[k], PD())
            master.set({"u_x_v": u[0], "u_y_v": u[1]})
            master.slave.doStep(k * TS, TS)
    finally:
        master.close()
    assert np.abs(q_true - run.trace.q_m).max() <= 1e-9
    assert np.abs(q_true - ref.q_d).max() > 1e-6  # the loop has a tracking error: the comparison sees dynamics


def test_a_step_of_five_samples_is_five_steps_of_one(either):
    """The inputs held over a 1 ms step give the state that five 0.2 ms steps with the same inputs give."""
    rig_fmu, unpacked = either
    finals = []
    for step, count in ((TS, 50), (5 * TS, 10)):
        master = Master(rig_fmu, unpacked, {"start.dx_m_s": 0.1})
        try:
            master.set({"u_x_v": 1.5, "u_y_v": -2.0, "d_y_v": 0.3})
            for k in range(count):
                master.slave.doStep(k * step, step)
            finals.append(master.get(OUTPUTS))
        finally:
            master.close()
    assert np.array_equal(finals[0], finals[1])
    assert abs(finals[0][4]) > 1e-4  # it moved (x_true_m)


@pytest.mark.parametrize("step_s", [1e-4, 3e-4, 2.5e-4, 0.0, -2e-4])
def test_a_step_that_is_not_whole_samples_is_refused_by_the_python_fmu_naming_it(rig_fmu, unpacked, step_s, capsys):
    """Refused with a line logged at fmi2Error; pythonfmu 0.7.0 returns a refused step as fmi2Discard (docs/fmi.md)."""
    master = Master(rig_fmu, unpacked, {})
    try:
        with pytest.raises(FMICallException, match=r"status 2 \(discard\)"):
            master.slave.doStep(0.0, step_s)
    finally:
        master.close()
    printed = capsys.readouterr().out
    why = f"communication step {step_s!r} s is not a whole multiple of the plant's sample period 0.0002 s"
    assert f"[ERROR] doStep at t = 0.0 s: {why}" in printed


@pytest.mark.parametrize(
    ("name", "what"), [("u_x_v", "non-finite command after 0 samples"), ("d_y_v", "disturbance (0.0, nan) V")]
)
def test_a_non_finite_input_is_refused_by_the_python_fmu_naming_it(rig_fmu, unpacked, name, what, capsys):
    master = Master(rig_fmu, unpacked, {})
    try:
        master.set({name: float("nan")})
        with pytest.raises(FMICallException, match=r"status 2 \(discard\)"):
            master.slave.doStep(0.0, TS)
        master.set({name: 0.0})
        master.slave.doStep(0.0, TS)  # the instance goes on
    finally:
        master.close()
    assert f"[ERROR] doStep at t = 0.0 s: {what}" in capsys.readouterr().out


def test_whole_samples():
    assert [whole_samples(s, TS) for s in (2e-4, 1e-3, 0.01, 2e-4 * 7)] == [1, 5, 50, 7]
    assert [whole_samples(s, TS) for s in (1e-4, 3e-4, 0.0, -2e-4, float("nan"), float("inf"))] == [None] * 6


def test_a_heavier_payload_set_on_the_fmu_moves_less(either):
    """The payload parameter reaches the plant: the same push from rest moves 5 kg more by less."""
    rig_fmu, unpacked = either
    moved = []
    for mass in (0.0, 5.0):
        master = Master(rig_fmu, unpacked, {"payload.mass_kg": mass})
        try:
            master.set({"u_x_v": 3.0})
            master.slave.doStep(0.0, 0.02)
            moved.append(master.get(["x_true_m"])[0])
        finally:
            master.close()
    assert 0.0 < moved[1] < moved[0]


@pytest.mark.parametrize(("payload_kg", "coulomb_n"), [(0.0, None), (5.0, None), (0.0, 20.0)])
@pytest.mark.parametrize("python", [False, True])
def test_the_paper_plant_fmu_moves_as_the_reference_machine_computes(tmp_path, payload_kg, coulomb_n, python):
    """The paper's plant pushed from rest by 3 V on X, at 1 ms steps, its payload and Coulomb level set as FMU
    parameters: the closed form of m x'' = kf u - B x' - Fc (tests/helpers.py) to 1 um over 0.1 s."""
    fmu = export_plant(tmp_path / "paper.fmu", "paper", python=python).path
    parameters = {"payload.mass_kg": payload_kg}
    if coulomb_n is not None:
        parameters["friction.x.fc_n"] = coulomb_n
    master = Master(fmu, Path(extract(str(fmu), str(tmp_path / "unpacked"))), parameters)
    x = []
    try:
        master.set({"u_x_v": 3.0})
        for k in range(100):
            master.slave.doStep(k * 1e-3, 1e-3)
            x.append(master.get(["x_true_m"])[0])
    finally:
        master.close()
    t = np.arange(1, 101) * 1e-3
    np.testing.assert_allclose(x, pushed_from_rest_m(t, 0, 3.0, payload_kg, coulomb_n), rtol=0, atol=1e-6)


def run_export(*argv: str) -> int:
    parser = argparse.ArgumentParser(prog="gantry-twin fmu")
    fmu_export.add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["export", *argv])
    return args.func(args)


@pytest.mark.parametrize("python", [False, True])
def test_fmu_export_writes_the_paper_plant_and_says_what_it_needs(tmp_path, capsys, python):
    out = tmp_path / "paper.fmu"
    argv = ["--plant", "paper", "--out", str(out), "--payload-kg", "5", "--set", "friction.x.fc_n=7"]
    assert run_export(*argv, *(["--python"] if python else [])) == 0
    printed = capsys.readouterr().out
    needs = f"gantry-twin {package_version()} installed" if python else "needs Linux x86-64 and its C library"
    assert str(out) in printed and needs in printed
    assert ("pythonfmu FMI 2.0" if python else "native FMI 2.0") in printed
    assert validate_fmu(str(out)) == []
    start = {v.name: float(v.start) for v in read_model_description(str(out)).modelVariables if v.start is not None}
    assert start["payload.mass_kg"] == 5.0 and start["friction.x.fc_n"] == 7.0
    assert "friction.x.sigma0_n_m" not in start  # the paper's plant has Coulomb friction


def test_the_reference_backend_steps_the_plant_as_the_compiled_one():
    """CoSimPlant on the interpreter (mujoco.mj_step, uncompiled kernels) gives the compiled samples' doubles."""
    outputs = []
    for compiled in (True, False):
        cosim = CoSimPlant(Plant.shipped("rig"), np.array([0.01, -0.02]), np.array([0.05, 0.0]), compiled=compiled)
        for k in range(20):
            assert cosim.advance(3, np.array([1.0 + 0.1 * k, -0.5]), np.array([0.0, 0.2])) is None
        outputs.append(cosim.outputs())
    assert outputs[0] == outputs[1]
    assert outputs[0]["x_m"] != outputs[0]["x_true_m"]  # quantised: the encoder is not the truth


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--set", "friction.x.fc_n"], "--set 'friction.x.fc_n': expected NAME=VALUE"),
        (["--set", "friction.x.fc_n=nan"], "expected NAME=VALUE with a finite number"),
        (["--set", "friction.z.fc_n=1"], "friction.z.fc_n: not a parameter of the rig plant"),
        (["--plant", "paper", "--set", "friction.x.sigma0_n_m=1e6"], "friction.x.sigma0_n_m: not a parameter"),
        (["--set", "friction.x.sigma0_n_m=1e12"], "friction.x.sigma0_n_m: must be in"),
        (["--set", "friction.y.fc_n=-1"], "friction.y.fc_n"),
    ],
)
def test_fmu_export_refuses_a_bad_parameter_naming_it_and_writes_nothing(tmp_path, argv, message):
    out = tmp_path / "plant.fmu"
    with pytest.raises(BadInput, match=re.escape(message)):
        run_export("--out", str(out), *argv)
    assert list(tmp_path.iterdir()) == []


def test_fmu_export_refuses_an_out_that_is_a_directory(tmp_path):
    with pytest.raises(BadInput, match="is a directory, not a regular file"):
        run_export("--out", str(tmp_path))
    assert list(tmp_path.iterdir()) == []


#: A process where gantry-twin cannot be imported loads the FMU: the FMU's own line says what it needs.
WITHOUT_GANTRY_TWIN = """
import sys
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
fmu, where = sys.argv[1:]
md = read_model_description(fmu)
sys.modules["gantry_twin"] = None  # as if not installed: every import of it fails
slave = FMU2Slave(guid=md.guid, unzipDirectory=extract(fmu, where), modelIdentifier="GantryPlant", instanceName="p")
try:
    slave.instantiate(loggingOn=True)
except Exception as exc:
    print("refused:", exc)
"""


def test_without_gantry_twin_the_fmu_refuses_to_instantiate_saying_what_it_needs(rig_fmu, tmp_path):
    done = subprocess.run(
        [sys.executable, "-c", WITHOUT_GANTRY_TWIN, str(rig_fmu), str(tmp_path / "unpacked")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert "gantry-twin's plant FMU needs a Python with gantry-twin installed" in done.stdout
    assert "refused: Failed to instantiate model" in done.stdout


def test_a_parameter_out_of_range_fails_initialisation_naming_it(rig_fmu, unpacked, capsys):
    """pythonfmu reports the slave's exception as fmi2Fatal: the instance is dropped (last in this module: a fatal
    instance is never freed)."""
    with pytest.raises(FMICallException, match=r"status 4 \(fatal\)"):
        Master(rig_fmu, unpacked, {"payload.mass_kg": 30.0})
    assert "payload.mass_kg: must be in [0, 20] kg, got 30.0" in capsys.readouterr().out
