"""The native plant FMU (docs/fmi.md, "The plant as an FMU"): its C gives the twin's plant to the bit, from fmpy and
from a C master with no Python; its state is MuJoCo's, saved and restored; it refuses what the Python FMU refuses,
in the same words, with fmi2Error; without a C compiler the export says so and names --python."""

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

from gantry_twin.cli import fmu_export
from gantry_twin.cli.common import BadInput
from gantry_twin.fmi.plant import INPUTS, OUTPUTS, CoSimPlant, build_plant, default_parameters
from gantry_twin.fmi.plant_export import export_plant
from gantry_twin.fmi.plant_native import mujoco_library
from gantry_twin.plant.model import Plant, default_model_path

TS = 2e-4
FMI2_ERROR = 3
HERE = Path(__file__).resolve().parent


def stimulus(seconds: float = 2.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(samples per communication step (n,), inputs (n, 4) V): steps and reversals of the commands, a chirp on each
    axis (1 to 40 Hz), a disturbance step and a disturbance chirp, over ``seconds`` s of 0.2 ms samples; the
    communication steps 1, 1, 5, 1, 3 samples in turn."""
    counts, rows, t, k = [], [], 0.0, 0
    pattern = (1, 1, 5, 1, 3)
    rng = np.random.default_rng(seed)
    while t < seconds:
        count = pattern[k % len(pattern)]
        square = 3.0 if (t // 0.25) % 2 == 0 else -3.0  # a reversal every 0.25 s
        chirp = np.sin(2.0 * np.pi * (1.0 + 19.5 * t / seconds) * t)
        u_x = (2.0 if t < 0.5 else -2.5) if t < 1.0 else 4.0 * chirp  # steps, a reversal, then a chirp
        u_y = square + 0.5 * chirp + 0.01 * rng.standard_normal()
        d_x = 0.3 if 0.7 <= t < 1.3 else 0.0
        d_y = 0.2 * np.sin(2.0 * np.pi * 30.0 * t * t)
        counts.append(count)
        rows.append((u_x, u_y, d_x, d_y))
        t += count * TS
        k += 1
    return np.array(counts), np.array(rows)


def twin_outputs(model: str, parameters: dict[str, float], counts: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    """The twin's own open-loop plant (the loop's compiled samples, fmi/plant.py) under the stimulus: (n, 8)."""
    values = default_parameters(Plant.shipped(model)) | parameters
    plant = build_plant(default_model_path(model), model == "rig", values)
    start = [values[f"start.{s}"] for s in ("x_m", "y_m", "dx_m_s", "dy_m_s")]
    cosim = CoSimPlant(plant, np.array(start[:2]), np.array(start[2:]), compiled=True)
    out = np.zeros((len(counts), len(OUTPUTS)))
    for k, (count, row) in enumerate(zip(counts, inputs, strict=True)):
        assert cosim.advance(int(count), row[:2], row[2:]) is None
        out[k] = list(cosim.outputs().values())
    return out


class Native:
    """A native plant FMU instantiated by fmpy, its variables by name; freed by close() whatever happened."""

    def __init__(self, fmu: Path, unpacked: Path, parameters: dict[str, float] | None = None) -> None:
        md = read_model_description(str(fmu))
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.slave = FMU2Slave(
            guid=md.guid, unzipDirectory=str(unpacked), modelIdentifier="GantryPlant", instanceName="plant"
        )
        self.slave.instantiate(loggingOn=True)
        try:
            self.slave.setupExperiment(startTime=0.0)
            self.slave.enterInitializationMode()
            self.set(parameters or {})
            self.slave.exitInitializationMode()
        except FMICallException:
            self.slave.freeInstance()  # FMI 2.0 allows fmi2FreeInstance (not fmi2Terminate) after fmi2Error
            raise

    def set(self, values: dict[str, float]) -> None:
        self.slave.setReal([self.vr[n] for n in values], [float(v) for v in values.values()])

    def get(self, names=OUTPUTS) -> np.ndarray:  # noqa: ANN001
        return np.array(self.slave.getReal([self.vr[n] for n in names]))

    def run(self, counts: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        out, t = np.zeros((len(counts), len(OUTPUTS))), 0.0
        for k, (count, row) in enumerate(zip(counts, inputs, strict=True)):
            self.set(dict(zip(INPUTS, row, strict=True)))
            self.slave.doStep(t, count * TS)
            t += count * TS
            out[k] = self.get()
        return out

    def close(self) -> None:
        try:
            self.slave.terminate()
        finally:
            self.slave.freeInstance()


@pytest.fixture(scope="module")
def fmus(tmp_path_factory) -> dict[str, tuple[Path, Path]]:
    """The native FMU of each machine, written by the export and unpacked once: {model: (fmu, unpacked)}."""
    where = tmp_path_factory.mktemp("native")
    found = {}
    for model in ("rig", "paper"):
        fmu = export_plant(where / f"{model}.fmu", model).path
        found[model] = (fmu, Path(extract(str(fmu), str(where / f"{model}-unpacked"))))
    yield found
    for _, unpacked in found.values():
        shutil.rmtree(unpacked, ignore_errors=True)


CASES = [
    ("rig", {}),
    ("paper", {}),
    ("rig", {"payload.mass_kg": 5.0, "start.x_m": 0.01, "start.dx_m_s": 0.05, "start.dy_m_s": -0.02}),
    ("paper", {"payload.mass_kg": 5.0, "friction.x.fc_n": 20.0, "start.y_m": -0.03, "start.dy_m_s": 0.1}),
]


@pytest.mark.parametrize(("model", "parameters"), CASES)
def test_the_native_fmu_steps_the_twins_plant_to_the_bit(fmus, model, parameters):
    """2 s of steps, reversals, chirps and disturbances at mixed communication steps: every output of every step
    equals the twin's compiled plant's, bit for bit (the C does the twin's operations in its order, without fused
    multiply-add, and calls the same libmujoco and C library)."""
    counts, inputs = stimulus()
    fmu, unpacked = fmus[model]
    native = Native(fmu, unpacked, parameters)
    try:
        ours = native.run(counts, inputs)
    finally:
        native.close()
    theirs = twin_outputs(model, parameters, counts, inputs)
    np.testing.assert_array_equal(ours, theirs)
    assert np.abs(theirs[:, 4:6]).max() > 1e-3  # it moved
    assert np.any(theirs[:, 0] != theirs[:, 4])  # and the encoder is quantised, not the truth


def test_the_rig_plant_fmu_differs_from_the_paper_plant(fmus):
    """The comparison above sees the rig's own effects: the same stimulus moves the two machines differently."""
    counts, inputs = stimulus(0.2)
    outputs = []
    for model in ("rig", "paper"):
        native = Native(*fmus[model])
        try:
            outputs.append(native.run(counts, inputs))
        finally:
            native.close()
    assert np.abs(outputs[0][:, 4:6] - outputs[1][:, 4:6]).max() > 1e-6


def c_master(tmp_path: Path) -> Path:
    """tests/fmi_master.c compiled against fmpy's FMI 2.0 headers (skips without a C compiler)."""
    import fmpy

    compiler = shutil.which("cc")
    if compiler is None:
        pytest.skip("no C compiler")
    master = tmp_path / "fmi_master"
    headers = Path(fmpy.__file__).parent / "c-code"
    command = [compiler, "-O2", "-std=c99", f"-I{headers}", str(HERE / "fmi_master.c"), "-ldl", "-o", str(master)]
    subprocess.run(command, check=True, capture_output=True, timeout=120)
    return master


def test_a_c_master_without_python_gets_the_twins_plant(fmus, tmp_path):
    """A C program (dlopen and the FMI 2.0 calls, with an empty environment: no Python, no LD_LIBRARY_PATH; the
    FMU's library finds libmujoco beside it) drives the rig FMU through the stimulus: the twin's outputs, to the
    bit (printed with 17 digits, read back exactly)."""
    fmu, unpacked = fmus["rig"]
    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    counts, inputs = stimulus()
    parameters = {"start.x_m": 0.02, "start.dy_m_s": 0.03}
    argv = [f"in={vr[n]}" for n in INPUTS] + [f"out={vr[n]}" for n in OUTPUTS]
    argv += [f"{vr[n]}={v!r}" for n, v in parameters.items()]
    rows = np.column_stack([counts * TS, inputs])
    lines = "".join(" ".join(repr(float(x)) for x in row) + "\n" for row in rows)
    done = subprocess.run(
        [str(c_master(tmp_path)), str(unpacked), md.guid, *argv],
        input=lines,
        capture_output=True,
        text=True,
        env={},
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("\n") == len(counts)
    ours = np.array([[float(x) for x in line.split()] for line in done.stdout.splitlines()])
    np.testing.assert_array_equal(ours, twin_outputs("rig", parameters, counts, inputs))


def test_the_fmu_carries_mujoco_its_licence_and_the_machine(fmus):
    fmu, _ = fmus["rig"]
    names = set(zipfile.ZipFile(fmu).namelist())
    library = f"binaries/linux64/{mujoco_library().name}"
    assert {
        "binaries/linux64/GantryPlant.so",
        library,
        "resources/model.xml",
        "binaries/linux64/mujoco-LICENSE",
    } <= names
    assert "Apache License" in zipfile.ZipFile(fmu).read("binaries/linux64/mujoco-LICENSE").decode()
    needed = subprocess.run(["readelf", "-d", str(fmus["rig"][1] / "binaries/linux64/GantryPlant.so")],
                            capture_output=True, text=True, check=False).stdout  # fmt: skip
    if needed:  # binutils present
        assert "$ORIGIN" in needed and mujoco_library().name in needed
        assert "python" not in needed.lower()
    md = read_model_description(str(fmu))
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
    assert "no Python" in md.description


def test_the_state_saved_and_restored_repeats_the_steps_to_the_bit(fmus):
    """fmi2GetFMUstate (MuJoCo's mj_getState and the encoder), serialised and read back: the steps after it repeat
    exactly, and a state set from before goes back in time."""
    counts, inputs = stimulus(0.4)
    half = len(counts) // 2
    native = Native(*fmus["rig"])
    try:
        native.run(counts[:half], inputs[:half])
        saved = native.slave.getFMUstate()
        at_save = native.get()
        first = native.run(counts[half:], inputs[half:])
        data = native.slave.serializeFMUstate(saved)
        native.slave.freeFMUstate(saved)
        restored = native.slave.deSerializeFMUstate(data)
        native.slave.setFMUstate(restored)
        np.testing.assert_array_equal(native.get(), at_save)
        again = native.run(counts[half:], inputs[half:])
        native.slave.freeFMUstate(restored)
    finally:
        native.close()
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(first[-1], at_save)


@pytest.mark.parametrize("step_s", [1e-4, 3e-4, 2.5e-4, 0.0, -2e-4, float("nan")])
def test_a_step_that_is_not_whole_samples_is_an_error_naming_it(fmus, step_s, capsys):
    """fmi2Error with the Python FMU's line; nothing moved, so the instance takes the next whole step."""
    native = Native(*fmus["rig"])
    try:
        with pytest.raises(FMICallException, match=r"status 3 \(error\)"):
            native.slave.doStep(0.0, step_s)
        native.slave.doStep(0.0, TS)
    finally:
        native.close()
    why = f"communication step {step_s!r} s is not a whole multiple of the plant's sample period 0.0002 s"
    assert f"[ERROR] doStep at t = 0.0 s: {why}" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("name", "what"), [("u_x_v", "non-finite command after 0 samples"), ("d_y_v", "disturbance (0.0, nan) V")]
)
def test_a_non_finite_input_is_an_error_naming_it(fmus, name, what, capsys):
    native = Native(*fmus["rig"])
    try:
        native.set({name: float("nan")})
        with pytest.raises(FMICallException, match=r"status 3 \(error\)"):
            native.slave.doStep(0.0, TS)
        native.set({name: 0.0})
        native.slave.doStep(0.0, TS)  # nothing moved: the instance goes on
    finally:
        native.close()
    assert f"[ERROR] doStep at t = 0.0 s: {what}" in capsys.readouterr().out


BAD_PARAMETERS = [
    ("rig", "payload.mass_kg", 30.0),
    ("rig", "payload.mass_kg", float("nan")),
    ("rig", "friction.x.fc_n", 0.0),
    ("rig", "friction.y.sigma0_n_m", 1e12),
    ("rig", "friction.x.vs_m_s", 1.0),
    ("rig", "friction.y.sigma2_ns_m", float("inf")),
    ("rig", "friction.x.fs_n", 100.0),
    ("rig", "friction.x.fc_n", 1e-3),
    ("rig", "friction.y.sigma1_ns_m", 2e4),
    ("paper", "friction.x.fc_n", -1.0),
    ("paper", "friction.y.sigma2_ns_m", float("inf")),
    ("paper", "payload.mass_kg", -0.5),
]


@pytest.mark.parametrize(("model", "name", "value"), BAD_PARAMETERS)
def test_a_bad_parameter_is_an_error_in_the_twins_words(fmus, model, name, value, capsys):
    """fmi2ExitInitializationMode returns fmi2Error and logs build_plant's own message for the value."""
    values = default_parameters(Plant.shipped(model)) | {name: value}
    with pytest.raises(ValueError) as refused:
        build_plant(default_model_path(model), model == "rig", values)
    with pytest.raises(FMICallException, match=r"status 3 \(error\)"):
        Native(*fmus[model], {name: value})
    assert f"[ERROR] parameter {str(refused.value).splitlines()[0]}" in capsys.readouterr().out


def test_a_start_that_is_not_finite_is_an_error(fmus, capsys):
    with pytest.raises(FMICallException, match=r"status 3 \(error\)"):
        Native(*fmus["rig"], {"start.dx_m_s": float("nan")})
    assert "[ERROR] parameter start.dx_m_s: must be a finite number, got nan" in capsys.readouterr().out


def test_a_parameter_after_initialisation_is_refused(fmus, capsys):
    native = Native(*fmus["paper"])
    try:
        with pytest.raises(FMICallException, match=r"status 3 \(error\)"):
            native.set({"payload.mass_kg": 1.0})
    finally:
        native.close()
    assert "payload.mass_kg is a fixed parameter, set before fmi2ExitInitializationMode" in capsys.readouterr().out


def run_export(*argv: str) -> int:
    parser = argparse.ArgumentParser(prog="gantry-twin fmu")
    fmu_export.add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["export", *argv])
    return args.func(args)


def test_without_a_c_compiler_the_export_says_so_and_names_python(tmp_path, monkeypatch):
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    out = tmp_path / "plant.fmu"
    with pytest.raises(BadInput, match=re.escape("no C compiler found") + ".*--python builds the pythonfmu one"):
        run_export("--out", str(out))
    assert list(tmp_path.iterdir()) == []


def test_after_a_refused_initialisation_a_reset_instance_starts_with_good_parameters(fmus):
    """fmi2Reset after fmi2Error: back to the defaults, and the next initialisation builds the plant."""
    fmu, unpacked = fmus["paper"]
    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    slave = FMU2Slave(guid=md.guid, unzipDirectory=str(unpacked), modelIdentifier="GantryPlant", instanceName="p")
    slave.instantiate()
    try:
        slave.enterInitializationMode()
        slave.setReal([vr["payload.mass_kg"]], [30.0])
        with pytest.raises(FMICallException, match=r"status 3 \(error\)"):
            slave.exitInitializationMode()
        slave.reset()
        assert slave.getReal([vr["payload.mass_kg"]]) == [0.0]
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        slave.setReal([vr["u_x_v"]], [3.0])
        slave.doStep(0.0, 10 * TS)
        assert slave.getReal([vr["x_true_m"]])[0] > 0.0
        slave.terminate()
    finally:
        slave.freeInstance()


#: A Python that cannot import gantry_twin nor mujoco runs the FMU with fmpy alone.
WITHOUT_THE_TWIN = """
import sys
sys.modules["gantry_twin"] = None
sys.modules["mujoco"] = None
from fmpy import simulate_fmu
result = simulate_fmu(sys.argv[1], stop_time=0.01, start_values={"u_x_v": 2.0}, output=["x_true_m"])
print(len(result), result["x_true_m"][-1])
"""


def test_the_fmu_runs_where_neither_gantry_twin_nor_mujoco_can_be_imported(fmus):
    """fmpy's simulate_fmu in a Python where importing gantry_twin or mujoco fails: the FMU's own libmujoco runs
    it, and it moves as the twin's plant (a fresh virtual environment with fmpy alone was checked by hand:
    docs/fmi.md)."""
    fmu, unpacked = fmus["paper"]
    done = subprocess.run(
        [sys.executable, "-c", WITHOUT_THE_TWIN, str(fmu)], capture_output=True, text=True, timeout=120, check=False
    )
    assert done.returncode == 0, done.stderr
    rows, x = done.stdout.split()
    counts, inputs = np.full(50, 1), np.tile([2.0, 0.0, 0.0, 0.0], (50, 1))
    assert int(rows) == 51 and float(x) == twin_outputs("paper", {}, counts, inputs)[-1, 4]
