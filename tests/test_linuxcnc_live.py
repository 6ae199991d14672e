"""LinuxCNC's live mode (docs/linuxcnc.md): LinuxCNC runs with the twin as its machine, driven by the tests'
headless display program (tests/data/linuxcnc/display_live.py).

LinuxCNC's shared memory is the machine's: every LinuxCNC these tests start runs inside
:func:`gantry_twin.cnc.session.machine_lock` (the offline mode's runs take it too), and each session ends with a
look, still inside the lock, for what it could have left: processes, shared-memory segments (HAL's FIFOs are
segments), the launcher's files. Without Debian's ``linuxcnc-uspace`` they are skipped, saying so.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from gantry_twin.cnc import session as cnc_session
from gantry_twin.cnc.live import HISTORY_PERIODS, LOOKAHEAD_PERIODS, LiveCommands
from gantry_twin.cnc.session import Session, machine_lock
from gantry_twin.paths.contours import ReferenceEnded

from .helpers import linuxcnc_turn, read_rrd, scalars

ROOT = Path(__file__).resolve().parents[1]
DISPLAY = ROOT / "tests" / "data" / "linuxcnc" / "display_live.py"
MISSING = cnc_session.missing()
needs_linuxcnc = pytest.mark.skipif(MISSING is not None, reason=f"LinuxCNC is not installed here: {MISSING}")
#: A 2 s program: a line, a half circle, two lines back to the start (F3000: 50 mm/s).
PROGRAM = "G21 G90 G64 P0.01\nG1 X20 Y0 F3000\nG3 X20 Y20 I0 J10\nG1 X0 Y20\nG1 X0 Y0\nM2\n"
#: 20 V on X's input from the twin's t = 3 s: twice what the controller can answer, X runs into its end stop.
FAULT_SCENARIO = """description: "live mode: X pushed into its end stop"
contour: {type: circle, radius_m: 0.2, timing: {rate_rad_s: 2.0, start: on_path}}
disturbance:
  x:
    - {type: step, value_v: 10.0, start_s: 3.0}
    - {type: step, value_v: 10.0, start_s: 3.0}
controller: {name: diarc}
"""
PROCESSES = {"linuxcnc", "rtapi_app", "milltask", "linuxcncsvr", "io", "halsampler", "halstreamer", "display_live.py"}


def leftovers(before: dict[int, tuple[int, int]], marker: str) -> list[str]:
    """What of a session is still on the machine: LinuxCNC's and HAL's processes, the twin (its command line names
    the session's INI), shared-memory segments that were not there before, the launcher's files."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            command = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode("utf-8", "replace")
        except OSError:
            continue
        name, state = stat[stat.index("(") + 1 : stat.rindex(")")], stat[stat.rindex(")") + 2 :][:1]
        if state != "Z" and (name in PROCESSES or marker in command):
            found.append(f"process {entry.name} {name}")
    now = cnc_session.shm_segments()
    found += [f"shared memory key {key:#x}" for key, (shmid, _) in now.items() if before.get(key, (None,))[0] != shmid]
    for pattern in ("linuxcnc.lock", "linuxcnc.debug.*", "linuxcnc.print.*"):
        found += [f"file {p}" for p in Path("/tmp").glob(pattern)]
    return found


def run_live(
    tmp_path: Path,
    program: str = "",
    wait_s: float = 0.0,
    scenario: Path | None = None,
    during=None,
    estop=False,
    telemetry: str = "",
) -> tuple[list[dict], Path, str]:
    """One LinuxCNC session of the live configuration with the tests' display: (its events, the twin's run
    directory, LinuxCNC's output). ``during(events_path)`` runs while LinuxCNC does. Nothing is left after it."""
    run_dir = tmp_path / "run"
    with linuxcnc_turn(), machine_lock():  # the tests' turn first (tests/helpers.py), then the sessions'
        before = cnc_session.shm_segments()
        directory = Session.make_directory()
        marker = str(directory)
        with Session(directory, directory / "gantry-twin.ini", DISPLAY.name) as session:
            display = directory / DISPLAY.name
            shutil.copyfile(DISPLAY, display)
            display.chmod(0o755)
            config = [sys.executable, "-m", "gantry_twin", "linuxcnc", "config", "--live", "--out", str(directory),
                      "--run-dir", str(run_dir), "--display", str(display)]  # fmt: skip
            if scenario is not None:
                config.insert(5, str(scenario))
            if telemetry:
                config.append(f"--telemetry={telemetry}")
            subprocess.run(config, check=True, capture_output=True, timeout=120, cwd=ROOT)
            events = directory / "events.jsonl"
            with open(directory / "gantry-twin.ini", "a", encoding="utf-8") as ini:
                ini.write(f"[GANTRY_TWIN_TEST]\nPROGRAM = {program}\nEVENTS = {events}\nWAIT_S = {wait_s}\n")
                ini.write(f"ESTOP = {int(estop)}\n")
            session.start()
            if during is not None:
                during(events)
            session.wait(240)
            said = [json.loads(line) for line in events.read_text().splitlines() if line.strip()]
            output = session.output()
        deadline = time.monotonic() + 20.0
        while (left := leftovers(before, marker)) and time.monotonic() < deadline:
            time.sleep(0.2)
    assert left == [], f"the session left {left}"
    return said, run_dir, output


def event(events: list[dict], name: str) -> dict:
    found = [e for e in events if e["event"] == name]
    assert found, f"no {name!r} among {[e['event'] for e in events]}: {events[-1] if events else ''}"
    return found[-1]


def trace(run_dir: Path) -> dict[str, np.ndarray]:
    parts = sorted((run_dir / "trace").glob("part-*.parquet"))
    assert parts, f"no trace parts in {run_dir}"
    table = pa.concat_tables([pq.read_table(p) for p in parts])
    return {name: table.column(name).to_numpy() for name in table.column_names}


# ---------------------------------------------------------------------------------------------- no LinuxCNC


class ListedFifos:
    """Stands for HAL's programs: the sampler's lines from a list, ``per_read`` at a time; what the twin writes goes."""

    delay_periods = 7

    def __init__(self, q_mm: np.ndarray, enabled: np.ndarray | None = None, per_read: int = 1000) -> None:
        on = np.ones(len(q_mm), dtype=bool) if enabled is None else enabled
        self.lines = [
            f"{k} {x:f} {y:f} 1 {int(e)} {k - 7} ".encode() for k, ((x, y), e) in enumerate(zip(q_mm, on, strict=True))
        ]
        self.at, self.per_read = 0, per_read

    def read(self, timeout_s: float):
        if self.at >= len(self.lines):
            return [], True
        self.at += self.per_read
        return self.lines[self.at - self.per_read : self.at], False

    def write(self, rows):
        pass

    def mark_end(self):
        pass

    cpu: dict = {}


def _commands(n: int = 400) -> np.ndarray:
    t = np.arange(n) * 1e-3
    return np.column_stack([20.0 * np.sin(3.0 * t) ** 2, 5.0 * t**2])  # mm


def test_the_reference_passes_through_every_command_and_its_rates_are_its_derivatives():
    q_mm = _commands()
    live = LiveCommands(ListedFifos(q_mm), 1e-3)
    t = np.arange(0, 0.39, 2e-4)
    ref = live.reference(t)
    at_servo = np.arange(0, len(t), 5)
    sent_m = np.round(q_mm[: len(at_servo)], 6) * 1e-3  # halsampler prints mm with 6 decimals
    assert np.max(np.abs(ref.q_d[at_servo] - sent_m)) < 1e-15
    # Independent: central differences of the interpolated position give its velocity and acceleration.
    h, inner = 1e-7, t[1:-1] + 0.37e-4  # never on a command (the acceleration's slope steps there)
    v_fd = (live.sample(inner + h).q_m - live.sample(inner - h).q_m) / (2 * h)
    a_fd = (live.sample(inner + h).v_m_s - live.sample(inner - h).v_m_s) / (2 * h)
    assert np.max(np.abs(v_fd - live.sample(inner).v_m_s)) < 1e-6
    assert np.max(np.abs(a_fd - live.sample(inner).a_m_s2)) < 1e-4
    # and the curve's velocity is the commands' own, to the Catmull-Rom's O(T^2)
    exact_v = np.column_stack([20.0 * 3.0 * np.sin(6.0 * t), 10.0 * t]) * 1e-3
    assert np.max(np.abs(ref.dq_d[10:] - exact_v[10:])) < 1e-5


def test_the_reference_is_causal_with_a_lookahead_of_two_servo_periods():
    q_mm = _commands()
    changed = q_mm.copy()
    changed[203:] += 1.0  # a jump 3 periods after t = 0.2 s
    t = np.arange(0.0, 0.2 + 1e-12, 2e-4)
    first, second = LiveCommands(ListedFifos(q_mm), 1e-3), LiveCommands(ListedFifos(changed), 1e-3)
    a, b = first.reference(t), second.reference(t)
    assert np.array_equal(a.q_d, b.q_d) and np.array_equal(a.dq_d, b.dq_d) and np.array_equal(a.ddq_d, b.ddq_d)
    assert LOOKAHEAD_PERIODS == 2
    late = LiveCommands(ListedFifos(np.where(np.arange(len(q_mm))[:, None] >= 202, q_mm + 1.0, q_mm)), 1e-3)
    assert not np.array_equal(late.reference(t).ddq_d, a.ddq_d)  # at t = 0.2 s the acceleration reads q(0.202 s)


def test_commands_taken_while_motion_is_disabled_are_held():
    q_mm = _commands()
    enabled = np.arange(len(q_mm)) < 100
    live = LiveCommands(ListedFifos(q_mm, enabled), 1e-3)
    ref = live.reference(np.arange(0, 0.3, 1e-3))
    assert np.allclose(ref.q_d[100:], q_mm[99] * 1e-3, atol=1e-15)


def test_a_long_run_holds_a_bounded_history_and_still_passes_through_its_commands():
    n = 3 * HISTORY_PERIODS
    q_mm = np.column_stack([np.arange(n) * 1e-3, np.zeros(n)])  # 1 mm/s along X
    live = LiveCommands(ListedFifos(q_mm), 1e-3)
    for first in range(0, n - 60, 50):  # the loop's chunks of 50 ms, in order
        ref = live.reference(np.arange(first, first + 50) * 1e-3)
    assert len(live._q) <= 2 * HISTORY_PERIODS and live.first > 0
    assert np.allclose(ref.q_d[:, 0], np.round(q_mm[first : first + 50, 0], 6) * 1e-3, atol=1e-15)
    assert np.allclose(ref.dq_d[:, 0], 1e-3, atol=1e-9)


def test_an_overrun_of_the_sampler_ends_the_run_as_a_fault():
    fifos = ListedFifos(_commands())
    fifos.lines.insert(30, b"overrun")
    live = LiveCommands(fifos, 1e-3)
    with pytest.raises(ReferenceEnded, match="sampler overran"):
        live.reference(np.arange(0, 0.1, 2e-4))
    assert live.overruns == 1 and live.info()["sampler_overruns"] == 1


def test_the_live_config_closes_the_estop_chain_only_through_the_twin(tmp_path):
    out = tmp_path / "config"
    done = subprocess.run([sys.executable, "-m", "gantry_twin", "linuxcnc", "config", "--live", "--out", str(out)],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)  # fmt: skip
    assert done.returncode == 0, done.stderr
    hal = (out / "gantry-twin.hal").read_text()
    assert "net estop-in and2.1.out => iocontrol.0.emc-enable-in" in hal
    assert (
        "net twin-alive watchdog.ok-out => and2.1.in1" in hal and "net x-fb mux2.0.out => joint.0.motor-pos-fb" in hal
    )
    assert f"linuxcnc machine --ini {out.resolve() / 'gantry-twin.ini'}" in hal
    bad = subprocess.run([sys.executable, "-m", "gantry_twin", "linuxcnc", "config", "--live", "--out", str(out),
                          "--delay-periods", "0"], capture_output=True, text=True, timeout=120, cwd=ROOT)  # fmt: skip
    assert bad.returncode == 2 and "--delay-periods 0" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1


@pytest.mark.skipif(shutil.which("halcmd") is None, reason="LinuxCNC's halcmd is not installed (linuxcnc-uspace)")
def test_the_twin_outside_linuxcnc_is_refused_in_one_line(tmp_path):
    out = tmp_path / "config"
    twin = [sys.executable, "-m", "gantry_twin", "linuxcnc"]
    config = [*twin, "config", "--live", "--out", str(out), "--run-dir", str(tmp_path / "run")]
    subprocess.run(config, check=True, capture_output=True, timeout=120, cwd=ROOT)
    machine = [*twin, "machine", "--ini", str(out / "gantry-twin.ini")]
    done = subprocess.run(machine, capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "no HAL session of the live configuration runs here" in done.stderr
    assert not (tmp_path / "run").exists()


# ---------------------------------------------------------------------------------------------- LinuxCNC runs


@pytest.fixture(scope="module")
def program_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("program") / "square_arc.ngc"
    path.write_text(PROGRAM)
    return path


@pytest.fixture(scope="module")
def live_program(tmp_path_factory, program_file):
    """The program run from LinuxCNC with the twin as its machine, once for the module."""
    if MISSING is not None:
        pytest.skip(f"LinuxCNC is not installed here: {MISSING}")
    return run_live(tmp_path_factory.mktemp("live"), str(program_file))


@pytest.fixture(scope="module")
def offline_program(tmp_path_factory, program_file):
    """The same program in the offline mode (LinuxCNC records, the twin tracks afterwards)."""
    if MISSING is not None:
        pytest.skip(f"LinuxCNC is not installed here: {MISSING}")
    out = tmp_path_factory.mktemp("offline") / "run"
    with linuxcnc_turn():
        done = subprocess.run([sys.executable, "-m", "gantry_twin", "run", str(program_file), "--cnc", "linuxcnc",
                               "--out", str(out)], capture_output=True, text=True, timeout=300, cwd=ROOT)  # fmt: skip
    assert done.returncode == 0, done.stderr
    table = pq.read_table(out / "trace.parquet")
    return {name: table.column(name).to_numpy() for name in table.column_names}


@needs_linuxcnc
def test_the_program_moves_the_twin_along_its_path(live_program):
    events, run_dir, _ = live_program
    done = event(events, "program_done")
    assert not done["estop"]
    data = trace(run_dir)
    x, y = data["x_d_m"] * 1e3, data["y_d_m"] * 1e3
    # The program's own corners and the arc's far point (30, 10) mm are on the commanded path.
    for point in ((20.0, 0.0), (30.0, 10.0), (20.0, 20.0), (0.0, 20.0)):
        assert np.min(np.hypot(x - point[0], y - point[1])) < 0.05, point
    # The twin's true position follows the commanded path within 0.1 mm everywhere.
    assert np.max(np.hypot(data["x_m"] * 1e3 - x, data["y_m"] * 1e3 - y)) < 0.1
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "ok"
    info = json.loads((run_dir / "linuxcnc_live.json").read_text())
    assert info["ended_by"].startswith("LinuxCNC ended") and info["sampler_overruns"] == 0


@needs_linuxcnc
def test_the_contour_error_is_the_offline_modes_size(live_program, offline_program):
    _, run_dir, _ = live_program
    live, offline = trace(run_dir), offline_program
    moving = np.hypot(np.gradient(live["x_d_m"]), np.gradient(live["y_d_m"])) > 0
    live_max = np.max(np.abs(live["eps_c_m"][moving]))
    offline_max = np.max(np.abs(offline["eps_c_m"]))
    live_rms = np.sqrt(np.mean(live["eps_c_m"][moving] ** 2))
    off_moving = np.hypot(np.gradient(offline["x_d_m"]), np.gradient(offline["y_d_m"])) > 0
    offline_rms = np.sqrt(np.mean(offline["eps_c_m"][off_moving] ** 2))
    assert 0.5 < live_max / offline_max < 2.0, (live_max, offline_max)
    assert 0.5 < live_rms / offline_rms < 2.0, (live_rms, offline_rms)


@needs_linuxcnc
def test_linuxcncs_following_error_is_the_twins_tracking_error(live_program):
    events, run_dir, _ = live_program
    done = event(events, "program_done")
    data = trace(run_dir)
    servo = np.arange(0, len(data["t_s"]), 5)
    e_mm = np.column_stack([data["x_meas_m"][servo] - data["x_d_m"][servo],
                            data["y_meas_m"][servo] - data["y_d_m"][servo]]) * 1e3  # fmt: skip
    # LinuxCNC's own largest |following error| of each joint is the twin's largest |error| at a servo instant:
    # its feedback is its command plus the twin's error (a loopback would give 0).
    for joint in range(2):
        assert done["ferror_highmark"][joint] == pytest.approx(np.max(np.abs(e_mm[:, joint])), abs=1e-6)
        assert 0.0 < done["ferror_highmark"][joint] < done["ferror_limit"][joint]
    # During the program, the following error LinuxCNC computed each time it was looked at is one of the twin's.
    ferror = np.array([s[2] for s in done["samples"]])
    assert len(ferror) > 50
    assert np.all(np.min(np.abs(-ferror[:, None] - e_mm[None, :, 0]), axis=1) < 1e-6)


@needs_linuxcnc
def test_halcmd_shows_the_feedback_as_the_command_plus_the_twins_error(live_program):
    events, run_dir, _ = live_program
    pins = event(events, "pins")
    assert "joint.0.motor-pos-fb <== x-fb" in pins["show"]
    data = trace(run_dir)
    servo = np.arange(0, len(data["t_s"]), 5)
    for joint, axis in enumerate("xy"):
        e_mm = (data[f"{axis}_meas_m"][servo] - data[f"{axis}_d_m"][servo]) * 1e3
        difference = pins["fb"][joint] - pins["cmd"][joint]
        # at rest after the program: the twin's error of a moment before (halcmd prints 7 digits)
        assert np.min(np.abs(e_mm[-2000:] - difference)) < 1e-6, (axis, difference)
    assert any(abs(f - c) > 0 for f, c in zip(pins["fb"], pins["cmd"], strict=True))  # not a loopback


@needs_linuxcnc
def test_the_feedback_delay_is_measured(live_program):
    _, run_dir, _ = live_program
    info = json.loads((run_dir / "linuxcnc_live.json").read_text())
    delay = info["delay_periods"]
    assert delay["periods_measured"] > 1000
    assert info["prefill_periods"] <= delay["min"] <= delay["median"] <= delay["p99"] <= delay["max"]
    assert info["delay_ms"]["median"] == pytest.approx(delay["median"] * 1.0)
    assert info["streamer_underruns"] == delay["max"] - info["prefill_periods"]


@needs_linuxcnc
def test_a_twin_fault_puts_linuxcnc_in_estop(tmp_path):
    scenario = tmp_path / "fault.yaml"
    scenario.write_text(FAULT_SCENARIO)
    events, run_dir, _ = run_live(tmp_path, "", 30.0, scenario)
    end = event(events, "end")
    assert end["estop"] and not end["enable_in"]
    info = json.loads((run_dir / "linuxcnc_live.json").read_text())
    assert info["ended_by"].startswith("the twin's fault: x touched its end stop")
    log = (run_dir / "linuxcnc_live.log").read_text()
    assert "the twin's fault raises LinuxCNC's estop: x touched its end stop" in log
    data = trace(run_dir)
    assert np.max(np.abs(data["x_m"])) > 0.25  # into the end stop's zone, independent of the twin's own check


@needs_linuxcnc
def test_linuxcncs_estop_ends_the_twins_run_cleanly_and_rerun_records_it(tmp_path):
    recording = tmp_path / "live.rrd"
    events, run_dir, _ = run_live(tmp_path, "", 3.0, estop=True, telemetry=f"--save {recording}")
    assert event(events, "end")["estop"]
    info = json.loads((run_dir / "linuxcnc_live.json").read_text())
    assert info["ended_by"] == "LinuxCNC's estop (iocontrol.0.user-enable-out fell)"
    assert json.loads((run_dir / "summary.json").read_text())["status"] == "ok"
    # rerun's recording of the twin holds its command of every sample, as its trace parts do
    u_x = scalars(read_rrd(recording), "inputs/u_x_V")[:, 0]
    parts = trace(run_dir)
    assert len(u_x) == len(parts["u_x_v"]) > 500
    np.testing.assert_array_equal(u_x.astype(np.float32), parts["u_x_v"])


def _twin_pid(run_dir: Path, events: Path) -> int:
    """The twin's pid (its log's first line), once the display has homed."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and '"homed"' not in (events.read_text() if events.exists() else ""):
        time.sleep(0.1)
    time.sleep(1.5)  # a trace part (1 s of the twin) written before it is stopped
    log = (run_dir / "linuxcnc_live.log").read_text()
    return int(log.split("(pid ")[1].split(")")[0])


@needs_linuxcnc
def test_a_stopped_twin_says_why_and_puts_linuxcnc_in_estop(tmp_path):
    def stop_the_twin(events: Path) -> None:
        os.kill(_twin_pid(tmp_path / "run", events), signal.SIGTERM)

    events, run_dir, _ = run_live(tmp_path, "", 20.0, during=stop_the_twin)
    end = event(events, "end")
    assert end["estop"] and not end["enable_in"]
    log = (run_dir / "linuxcnc_live.log").read_text()
    assert "the twin's fault raises LinuxCNC's estop: the twin stopped:" in log
    assert len(trace(run_dir)["t_s"]) > 0


@needs_linuxcnc
def test_a_killed_twin_puts_linuxcnc_in_estop(tmp_path):
    def kill_the_twin(events: Path) -> None:
        os.kill(_twin_pid(tmp_path / "run", events), signal.SIGKILL)

    events, run_dir, _ = run_live(tmp_path, "", 20.0, during=kill_the_twin)
    end = event(events, "end")
    assert end["estop"] and not end["enable_in"]
    assert not (run_dir / "summary.json").exists()
    assert len(trace(run_dir)["t_s"]) > 0  # the parts written before the kill are readable
