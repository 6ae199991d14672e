"""A user's controller FMU in the 0.2 ms loop (docs/fmi.md): a native FMI 2.0 co-simulation FMU built from C with
gcc (examples/fmu-pd/pd.c, the built-in pd law) runs in the compiled loop and gives pd's trajectory; its variables
go into the trace; calls that fail end the run with the trace kept; bad FMUs are refused in one line
(docs/hostile-input.md, "Controller FMUs"); its unpacked files are removed after the run, also on SIGINT.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

import gantry_twin
from gantry_twin import Plant, TimingLaw, circle, run_scenario, simulate
from gantry_twin.controllers import PD, Measurement, ReferenceSample, RunContext
from gantry_twin.controllers.base import REF_DDQ, REF_DQ, REF_Q
from gantry_twin.fmi import fmu_controller
from gantry_twin.fmi.controller import FmuController, PythonFmuController
from gantry_twin.fmi.description import read_controller
from gantry_twin.loop.trace import SimulationError
from gantry_twin.scenario import shipped

from .helpers import run_main

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "fmu-pd"
DOC = ROOT / "docs" / "hostile-input.md"
SECTION = "## Controller FMUs"
#: Where this process imported gantry_twin from (the source tree or an install): a child imports the same code, so
#: that it finds the loops this process compiled in numba's cache (keyed on the install path).
IMPORTED_FROM = str(Path(gantry_twin.__file__).resolve().parents[1])

pytestmark = pytest.mark.skipif(
    shutil.which("gcc") is None, reason="gcc not found: the test FMUs are built from C (examples/fmu-pd/pd.c) with gcc"
)

#: pd's gains (its defaults) as the FMU's parameters, named as examples/fmu-pd/modelDescription.xml names them.
_PD = PD()
GAINS = {
    f"{gain}_{axis}": float(value[i])
    for gain, value in (("kp", _PD.kp_v_m), ("kd", _PD.kd_v_s_m), ("kv", _PD.kv_v_s_m), ("ka", _PD.ka_v_s2_m))
    for i, axis in enumerate("xy")
}
#: The tests' failing controllers (pd.c's FAIL_AT_S, FAIL_STATUS, TERMINATE_STATUS): from t = 0.0099 s on, sample 50.
FAIL_AT_S, FAIL_STEP = 0.0099, 50


def _builder():
    spec = importlib.util.spec_from_file_location("fmu_pd_build", EXAMPLE / "build.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def build():
    return _builder().build_fmu


@pytest.fixture(scope="module")
def fmus(tmp_path_factory, build) -> dict[str, Path]:
    """pd.fmu and the failing variants, each in a directory of its own."""
    root = tmp_path_factory.mktemp("fmus")
    variants = {
        "pd": (),
        "step_error": (f"FAIL_AT_S={FAIL_AT_S}", "FAIL_STATUS=fmi2Error"),
        "step_discard": (f"FAIL_AT_S={FAIL_AT_S}", "FAIL_STATUS=fmi2Discard"),
        "terminate_error": ("TERMINATE_STATUS=fmi2Error",),
    }
    return {name: build(root / name, defines=defines) for name, defines in variants.items()}


def _scenario(fmu: Path | str, duration_s: float) -> str:
    """A scenario's text: the default circle for ``duration_s`` with the FMU at pd's gains."""
    options = json.dumps({"fmu": str(fmu), "parameters": GAINS})
    return f"duration_s: {duration_s}\ncontroller: {{name: fmu, options: {options}}}\n"


def _pd_and_fmu(fmu: Path, duration_s: float, **options) -> tuple:
    """The shipped no-load circle with pd, and with the FMU (pd's gains as its parameters), both compiled."""
    overrides = [f"duration_s={duration_s}"]
    fmu_options = json.dumps({"fmu": str(fmu), "parameters": GAINS, **options})
    pd = run_scenario(shipped("no_load_circle"), [*overrides, "controller.name=pd", "controller.options={}"])
    ours = run_scenario(shipped("no_load_circle"), [*overrides, f"controller={{name: fmu, options: {fmu_options}}}"])
    return pd, ours


def test_the_c_pd_fmu_gives_pds_trajectory_on_the_no_load_circle(fmus):
    """Acceptance: the same law in C (pd.c, the order of operations of controllers/pd.py, compiled without fused
    multiply-add) gives the same trajectory as ``controller: {name: pd}``, to 1e-12 m and in fact to the bit: every
    operation is an IEEE double operation in the same order on the same values, and the loop clips both commands
    the same way (pd's own clip to the same limits changes nothing)."""
    pd, ours = _pd_and_fmu(fmus["pd"], 1.0)
    assert ours.summary.controller == "fmu" and not ours.summary.failed
    assert ours.trace.filled == pd.trace.filled == 5000
    assert np.abs(ours.trace.q_m - pd.trace.q_m).max() <= 1e-12
    assert np.array_equal(ours.trace.q_m, pd.trace.q_m)
    assert np.array_equal(ours.trace.u_v, pd.trace.u_v)
    assert np.abs(pd.trace.e_m).max() > 1e-7  # a trajectory that tests the law (it is off the path at all)


def test_other_gains_give_another_trajectory(fmus):
    """The parameters reach the FMU: a stiffer kp_x changes the X axis's trajectory."""
    path, timing = circle(), TimingLaw(2.0, "on_path")
    plant = Plant()
    a = simulate(plant, path, timing, fmu_controller(fmus["pd"], parameters=GAINS), 0.1)
    b = simulate(plant, path, timing, fmu_controller(fmus["pd"], parameters={**GAINS, "kp_x": 2e4}), 0.1)
    assert not np.array_equal(a.q_m[:, 0], b.q_m[:, 0])


def test_every_signal_reaches_its_input_and_a_mapping_moves_one(fmus):
    """One sample through update() (the step uncompiled): the FMU's law on the signals it is given, by the formula
    computed here; with ``variables: {ddx_d_m_s2: t_s}`` the X feed-forward multiplies the sample's time."""
    rng = np.random.default_rng(7)
    q, dq, ref = rng.normal(size=2), rng.normal(size=2), rng.normal(size=9)
    t_s = 0.37
    context = RunContext(2e-4, np.array([1e9, 1e9]), Measurement(0.0, q, dq))
    for variables, ddx in (({}, ref[REF_DDQ]), ({"ddx_d_m_s2": "t_s"}, t_s)):
        controller = fmu_controller(fmus["pd"], variables=variables, parameters=GAINS)
        controller.reset(context)
        try:
            u = controller.update(Measurement(t_s, q, dq), ReferenceSample.from_row(ref))
        finally:
            controller.close()
        feed = (ddx, ref[REF_DDQ + 1])
        for i, a in enumerate("xy"):
            e, de = q[i] - ref[REF_Q + i], dq[i] - ref[REF_DQ + i]
            expected = -GAINS[f"kp_{a}"] * e - GAINS[f"kd_{a}"] * de + GAINS[f"kv_{a}"] * ref[REF_DQ + i]
            assert u[i] == expected + GAINS[f"ka_{a}"] * feed[i]


def test_the_python_loop_runs_the_same_step_to_the_bit(fmus):
    """The reference backend calls the FMU through ctypes (the same step, uncompiled): the same trace."""
    path, timing, plant = circle(), TimingLaw(2.0, "on_path"), Plant()
    controller = fmu_controller(fmus["pd"], parameters=GAINS, log_variables=("u_y_v",))
    assert isinstance(controller, FmuController)
    compiled = simulate(plant, path, timing, controller, 0.05, backend="compiled")
    reference = simulate(plant, path, timing, controller, 0.05, backend="reference")
    assert np.array_equal(compiled.q_m, reference.q_m)
    assert np.array_equal(compiled.controller_state["fmu_u_y_v"], reference.controller_state["fmu_u_y_v"])


def test_a_new_process_loads_the_fmus_loop_from_numbas_cache(fmus):
    """The loop takes the FMU's addresses as arguments: a new process (other addresses) loads it from the cache that
    this process filled, and it runs there (pd's trajectory)."""
    simulate(Plant(), circle(), TimingLaw(2.0, "on_path"), fmu_controller(fmus["pd"], parameters=GAINS), 0.01)
    code = f"""
import numpy as np
from gantry_twin import Plant, TimingLaw, circle, simulate
from gantry_twin.controllers import PD, Measurement, ReferenceSample, RunContext
from gantry_twin.controllers.base import REF_DDQ, REF_DQ, REF_Q
from gantry_twin.fmi import fmu_controller
from gantry_twin.loop.simulate import loop_needs_compiling
controller = fmu_controller({str(fmus["pd"])!r}, parameters={GAINS!r})
assert not loop_needs_compiling(controller), "compiles again"
a = simulate(Plant(), circle(), TimingLaw(2.0, "on_path"), controller, 0.05)
b = simulate(Plant(), circle(), TimingLaw(2.0, "on_path"), PD(), 0.05)
assert np.array_equal(a.q_m, b.q_m)
"""
    env = {**os.environ, "PYTHONPATH": IMPORTED_FROM}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr


def test_logged_variables_reach_the_trace_and_the_path_is_the_scenarios(fmus, tmp_path, capsys):
    """``--log-fmu-variables`` puts the FMU's variables into trace.parquet (fmu_<name>); ``fmu: pd.fmu`` is found
    beside the scenario file from any working directory, and the run's scenario.yaml names it absolutely."""
    here = tmp_path / "scenario"
    here.mkdir()
    shutil.copy(fmus["pd"], here / "pd.fmu")
    (here / "s.yaml").write_text(_scenario("pd.fmu", 0.1))
    out = tmp_path / "out"
    code, _, err = run_main(
        ["run", str(here / "s.yaml"), "--out", str(out), "--no-plots", "--log-fmu-variables", "u_x_v,u_y_v"], capsys
    )
    assert code == 0, err
    table = pq.read_table(out / "trace.parquet")
    for axis in "xy":
        logged = table.column(f"fmu_u_{axis}_v").to_numpy()
        assert np.array_equal(logged, table.column(f"u_{axis}_v").to_numpy())  # unclipped = clipped: no saturation
        assert np.abs(logged).max() > 0.01
    assert f"fmu: {here / 'pd.fmu'}" in (out / "scenario.yaml").read_text()


def test_log_fmu_variables_needs_an_fmu_controller(tmp_path, capsys):
    (tmp_path / "s.yaml").write_text("duration_s: 0.1\ncontroller: {name: pd}\n")
    code, _, err = run_main(["run", str(tmp_path / "s.yaml"), "--log-fmu-variables", "u_x_v"], capsys)
    assert code == 2
    assert err.strip() == "gantry-twin: error: --log-fmu-variables: the controller is pd, not fmu (docs/fmi.md)"


class _Unpacked:
    """An observer that counts the FMU directories under the temporary directory while the run goes."""

    def __init__(self, root: Path) -> None:
        self.root, self.seen = root, 0

    def on_start(self, run, trace):
        pass

    def on_chunk(self, trace, start, stop):
        self.seen = max(self.seen, len(list(self.root.glob("**/gantry-twin-fmu-*"))))  # in the worker's directory

    def on_end(self, trace):
        pass


@pytest.fixture
def private_tmp(tmp_path, monkeypatch) -> Path:
    root = tmp_path / "tmp"
    root.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(root))
    return root


@pytest.mark.parametrize("fails", [False, True])
def test_the_unpacked_fmu_is_removed_after_the_run(fmus, private_tmp, fails):
    """One directory while the run goes, none after it (a run that ends well, and one whose doStep fails)."""
    watch = _Unpacked(private_tmp)
    controller = fmu_controller(fmus["step_error" if fails else "pd"], parameters=GAINS)
    try:
        simulate(Plant(), circle(), TimingLaw(2.0, "on_path"), controller, 0.05, observers=[watch], chunk_s=0.002)
    except SimulationError:
        assert fails
    assert watch.seen == 1
    assert list(private_tmp.iterdir()) == []


def test_the_unpacked_fmu_is_removed_on_sigint(fmus, tmp_path):
    """``gantry-twin run`` stopped by SIGINT while the FMU runs: exit 130, its directory gone."""
    root = tmp_path / "tmp"
    root.mkdir()
    (tmp_path / "s.yaml").write_text(_scenario(fmus["pd"], 600))
    env = {**os.environ, "TMPDIR": str(root), "PYTHONPATH": IMPORTED_FROM}
    command = [sys.executable, "-m", "gantry_twin", "run", "s.yaml", "--out", "out", "--no-plots", "--no-progress"]
    child = subprocess.Popen(command, cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 180
        running = False  # the run's instance: a directory that stays (the build's trial start removes its own at once)
        while not running and time.monotonic() < deadline and child.poll() is None:
            time.sleep(0.5)
            running = bool(list(root.glob("**/gantry-twin-fmu-*")))  # the worker's own directory holds it
            if running:
                time.sleep(1.0)
                running = bool(list(root.glob("**/gantry-twin-fmu-*")))
        assert running, "the FMU was never unpacked for the run"
        child.send_signal(signal.SIGINT)
        _, err = child.communicate(timeout=60)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert child.returncode == 130, err
    assert list(root.iterdir()) == []


@pytest.mark.parametrize(("variant", "status"), [("step_error", "fmi2Error"), ("step_discard", "fmi2Discard")])
def test_a_failed_do_step_ends_the_run_with_the_trace_kept(fmus, tmp_path, capsys, variant, status):
    """doStep returning error or discard at sample 50: exit 1, one line naming the FMU file, the call and its
    status, and trace.parquet holding the 50 samples before it (summary.json: failed at step 50)."""
    (tmp_path / "s.yaml").write_text(_scenario(fmus[variant], 0.1))
    out = tmp_path / "out"
    code, _, err = run_main(["run", str(tmp_path / "s.yaml"), "--out", str(out), "--no-plots"], capsys)
    assert code == 1
    line = err.strip().splitlines()[-1]
    assert f"the controller failed at t = 0.0100 s (step {FAIL_STEP}): pd.fmu: fmi2DoStep returned {status}" in line
    assert pq.read_table(out / "trace.parquet").num_rows == FAIL_STEP
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and summary["failure"]["step"] == FAIL_STEP


def test_a_terminate_that_fails_after_the_run_fails_it_with_the_whole_trace(fmus):
    """An fmi2Terminate that fails after a run that went well: a SimulationError at the last sample, the whole
    trace kept. (The factory's trial start refuses such an FMU before any run: case fmu_terminate_fails; this one is
    made without it, as an FMU whose terminate fails only after a run would behave.)"""
    controller = FmuController(read_controller(fmus["terminate_error"], parameters=GAINS))
    with pytest.raises(SimulationError) as caught:
        simulate(Plant(), circle(), TimingLaw(2.0, "on_path"), controller, 0.02)
    assert str(caught.value) == (
        "closing the controller failed at t = 0.0198 s (step 99): pd.fmu: fmi2Terminate returned fmi2Error"
    )
    assert caught.value.trace.filled == 100 and not np.isnan(caught.value.trace.q_m).any()


def test_fmu_check_prints_the_mapping(fmus, capsys):
    code, out, err = run_main(["fmu", "check", str(fmus["pd"]), "--log-fmu-variables", "u_x_v"], capsys)
    assert code == 0, err
    assert "native: runs in the compiled loop" in out.splitlines()[0]
    assert "  x_m         -> input 'x_m' (vr 0)" in out.splitlines()
    assert "  t_s            (not an input of this FMU)" in out.splitlines()
    assert "  u_y_v       <- output 'u_y_v' (vr 11)" in out.splitlines()
    assert "  logged 'u_x_v' (vr 10)" in out.splitlines()
    assert "settable parameter 'kp_x' (start 10000.0)" in out


def test_fmu_check_maps_other_names(fmus, tmp_path, build, capsys):
    """``--map`` binds a variable named otherwise; without it the FMU is refused."""
    description = (EXAMPLE / "modelDescription.xml").read_text().replace('name="x_m"', 'name="pos_x"')
    fmu = build(tmp_path, description=description)
    code, _, err = run_main(["fmu", "check", str(fmu)], capsys)
    assert code == 2
    assert (
        err.strip()
        == "gantry-twin: error: pd.fmu: input 'pos_x' is bound to no signal; map it in variables (docs/fmi.md)"
    )
    code, out, err = run_main(["fmu", "check", str(fmu), "--map", "pos_x=x_m"], capsys)
    assert code == 0, err
    assert "  x_m         -> input 'pos_x' (vr 0)" in out.splitlines()


# -- bad FMUs: docs/hostile-input.md, "Controller FMUs" -------------------------------------------------------------


def _zip(path: Path, members: dict[str, bytes | str]) -> None:
    with zipfile.ZipFile(path, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)


def _make_case(case: str, directory: Path, build) -> str:
    """Write the case's pd.fmu into ``directory``; the scenario's controller options (YAML flow text)."""
    options = "fmu: pd.fmu"
    xml = (EXAMPLE / "modelDescription.xml").read_text()
    library = None
    if case not in ("fmu_missing", "fmu_not_a_zip"):
        library = zipfile.ZipFile(build(directory / "built")).read("binaries/linux64/pd.so")
    members: dict[str, bytes | str] = {"modelDescription.xml": xml, "binaries/linux64/pd.so": library}
    if case == "fmu_missing":
        return options
    if case == "fmu_not_a_zip":
        (directory / "pd.fmu").write_text("a text file named .fmu\n")
        return options
    if case == "fmu_without_model_description":
        del members["modelDescription.xml"]
    elif case == "fmu_model_exchange_only":
        members["modelDescription.xml"] = xml.replace(
            '<CoSimulation modelIdentifier="pd" canHandleVariableCommunicationStepSize="true"/>',
            '<ModelExchange modelIdentifier="pd"/>',
        )
    elif case == "fmu_fmi_3":
        members["modelDescription.xml"] = FMI3_DESCRIPTION
    elif case == "fmu_no_binary_for_this_platform":
        members["binaries/win64/pd.dll"] = members.pop("binaries/linux64/pd.so")
    elif case == "fmu_binary_not_loadable":
        members["binaries/linux64/pd.so"] = b"not a shared library\n"
    elif case == "fmu_terminate_fails":
        members["binaries/linux64/pd.so"] = zipfile.ZipFile(
            build(directory / "terminate", defines=("TERMINATE_STATUS=fmi2Error",))
        ).read("binaries/linux64/pd.so")
    elif case in ("fmu_segfault_on_start", "fmu_exit_on_start"):  # pd.c's MISBEHAVE: 1 a null write, 3 exit(3)
        kind = "1" if case == "fmu_segfault_on_start" else "3"
        members["binaries/linux64/pd.so"] = zipfile.ZipFile(
            build(directory / "start", defines=("MISBEHAVE_ON_START=1", f"MISBEHAVE={kind}"))
        ).read("binaries/linux64/pd.so")
    elif case == "fmu_mapped_variable_missing":
        options += ", variables: {pos_x: x_m}"
    elif case == "fmu_mapped_to_no_signal":
        options += ", variables: {x_m: position_x}"
    elif case == "fmu_output_not_real":
        members["modelDescription.xml"] = re.sub(
            r'(name="u_x_v" valueReference="10" causality="output" variability=")continuous(" initial="calculated">)'
            r"<Real/>",
            r"\1discrete\2<Integer/>",
            xml,
        )
    elif case == "fmu_input_not_causality_input":
        options += ", variables: {kp_x: x_m}"
    elif case == "fmu_convention_name_not_an_input":
        members["modelDescription.xml"] = xml.replace(
            'name="y_m" valueReference="1" causality="input" variability="continuous"><Real start="0"/>',
            'name="y_m" valueReference="1" causality="output" variability="continuous"><Real/>',
        )
    elif case == "fmu_description_invalid":
        members["modelDescription.xml"] = xml.replace(
            'name="y_m" valueReference="1" causality="input" variability="continuous"><Real start="0"/>',
            'name="y_m" valueReference="1" causality="local" variability="continuous"><Real start="0"/>',
        )
    elif case == "fmu_output_missing":
        members["modelDescription.xml"] = xml.replace('name="u_y_v"', 'name="u_y"')
    elif case == "fmu_parameter_not_a_parameter":
        options += ", parameters: {x_m: 1.0}"
    elif case == "fmu_parameter_infinite":
        options += ", parameters: {kp_x: .inf}"
    elif case == "fmu_log_variable_missing":
        options += ", log_variables: [e_x]"
    else:
        raise AssertionError(f"no such case {case}")
    _zip(directory / "pd.fmu", members)
    return options


#: A minimal FMI 3.0 co-simulation description (fmpy reads it).
FMI3_DESCRIPTION = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="3.0" modelName="pd" instantiationToken="{6f1d2c1e-5b0a-4c1e-9a53-7d2f0e3b8a11}">
  <CoSimulation modelIdentifier="pd"/>
  <ModelVariables>
    <Float64 name="time" valueReference="0" causality="independent" variability="continuous"/>
  </ModelVariables>
  <ModelStructure/>
</fmiModelDescription>
"""


def documented_cases() -> dict[str, str]:
    """case id -> the one-line answer, from docs/hostile-input.md's "Controller FMUs" table."""
    text = DOC.read_text(encoding="utf-8").split(SECTION, 1)[1].split("\n## ", 1)[0]
    return dict(re.findall(r"^\| `([^`]+)` \| .* \| `(.*)` \|$", text, flags=re.MULTILINE))


CASES = documented_cases() if SECTION in DOC.read_text(encoding="utf-8") else {}


def test_every_bad_fmu_case_is_documented():
    assert len(CASES) >= 12


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_bad_fmu_is_refused_in_one_line(case, tmp_path, build, capsys, monkeypatch):
    """``gantry-twin run s.yaml --out out`` with the case's pd.fmu beside s.yaml: exit 2, the documented line,
    nothing written."""
    options = _make_case(case, tmp_path, build)
    (tmp_path / "s.yaml").write_text(f"duration_s: 0.1\ncontroller: {{name: fmu, options: {{{options}}}}}\n")
    monkeypatch.chdir(tmp_path)
    code, out, err = run_main(["run", "s.yaml", "--out", "out"], capsys)
    assert code == 2, err
    assert err.strip().splitlines() == [CASES[case]]
    assert "Traceback" not in err and out == ""
    assert not (tmp_path / "out").exists()


@pytest.fixture(scope="module")
def python_fmu(tmp_path_factory) -> Path:
    """pd's law as an FMU built with pythonfmu (examples/fmu-pd/pypd.py)."""
    pytest.importorskip("pythonfmu")
    where = tmp_path_factory.mktemp("pythonfmu")
    command = [sys.executable, "-m", "pythonfmu", "build", "-f", str(EXAMPLE / "pypd.py"), "-d", str(where)]
    subprocess.run(command, check=True, capture_output=True)
    return where / "pypd.fmu"


def test_a_python_fmu_runs_on_the_python_loop(python_fmu):
    """An FMU built with pythonfmu: PythonFmuController (no compiled step); the Python loop runs pd's law in it."""
    controller = fmu_controller(python_fmu, parameters=GAINS)
    assert isinstance(controller, PythonFmuController)
    path, timing, plant = circle(), TimingLaw(2.0, "on_path"), Plant()
    ours = simulate(plant, path, timing, controller, 0.02)
    pd = simulate(plant, path, timing, PD(), 0.02)
    assert np.array_equal(ours.q_m, pd.q_m)


def test_a_python_fmus_run_says_so_and_its_cost(python_fmu, tmp_path, capsys):
    (tmp_path / "s.yaml").write_text(_scenario(python_fmu, 0.02))
    code, _, err = run_main(["run", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "out"), "--no-plots"], capsys)
    assert code == 0, err
    assert re.search(
        r"note: pypd\.fmu needs Python \(built with PythonFMU [^)]*\): it ran on the Python loop, \d+ us per "
        r"sample \(100 samples in",
        err,
    ), err
    code, out, _ = run_main(["fmu", "check", str(python_fmu)], capsys)
    assert code == 0 and "needs Python (built with pythonfmu): runs on the Python loop" in out
