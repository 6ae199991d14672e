"""LinuxCNC drives the twin (docs/linuxcnc.md): the configuration, the program as rs274 reads it, the offline mode.

The tests that run LinuxCNC need Debian's ``linuxcnc-uspace`` (``.ci/run``
installs it where apt exists); without it they are skipped, saying so. They
are all in this file, so that pytest-xdist's ``--dist loadfile`` runs them on
one worker, one LinuxCNC at a time (LinuxCNC's shared memory is the
machine's), and each checks that nothing of LinuxCNC is left after it.

The live mode's tests (the second half: LinuxCNC runs with the twin as its machine, driven by the tests'
headless display program, tests/data/linuxcnc/display_live.py) are here too, for the same reason.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from gantry_twin.cli import main
from gantry_twin.cnc import session as cnc_session
from gantry_twin.cnc.canon import read_canon
from gantry_twin.cnc.config import (
    INI_NAME,
    CncConfigError,
    config_files,
    followable,
    machine_from_ini,
    twin_machine,
)
from gantry_twin.cnc.live import HISTORY_PERIODS, LOOKAHEAD_PERIODS, LiveCommands
from gantry_twin.cnc.offline import DISPLAY_SCRIPT, CncRecord
from gantry_twin.cnc.reference import CncPath, attribute, read_run_files
from gantry_twin.cnc.session import Session, machine_lock
from gantry_twin.gcode.geometry import Move, MoveTable
from gantry_twin.gcode.part_error import nearest_on_program
from gantry_twin.gcode.planner import default_limits
from gantry_twin.gcode.program import TRAVEL_HALF_M, TRAVEL_MARGIN_M
from gantry_twin.gcode.reader import read_program
from gantry_twin.paths.contours import ReferenceEnded
from gantry_twin.reports.compare import load_run, program_plan

from .helpers import linuxcnc_turn, read_rrd, scalars

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data" / "linuxcnc"
SPLINE_PROGRAM = DATA / "inverse_time_spline.ngc"
MISSING = cnc_session.missing()
needs_linuxcnc = pytest.mark.skipif(MISSING is not None, reason=f"LinuxCNC is not installed here: {MISSING}")
needs_rs274 = pytest.mark.skipif(
    shutil.which("rs274") is None, reason="LinuxCNC's rs274 is not installed (linuxcnc-uspace)"
)
#: LinuxCNC's processes (their command names) and its shared-memory keys (HAL, RTAPI, NML: as its launcher makes them).
PROCESSES = {"linuxcnc", "rtapi_app", "milltask", "linuxcncsvr", "io", "halsampler", "display_offline"}
SHM_KEYS = {0x48414C32, 0x48484C34, 0x48534130, 0x64, *range(0x3E9, 0x3EE)}


def leftovers() -> list[str]:
    """What of LinuxCNC is on the machine: its processes (zombies aside), shared memory, lock, temporaries."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            name, state = stat[stat.index("(") + 1 : stat.rindex(")")], stat[stat.rindex(")") + 2 :][:1]
            if name in PROCESSES and state != "Z":
                found.append(f"process {entry.name} {name}")
    found += [f"shared memory key {key:#x}" for key in cnc_session.shm_segments() if key in SHM_KEYS]
    for pattern in ("linuxcnc.lock", "linuxcnc.debug.*", "linuxcnc.print.*", "gantry-twin-linuxcnc-*"):
        found += [f"file {p}" for p in Path("/tmp").glob(pattern)]
    return found


def wait_until_clean(limit_s: float = 30.0) -> list[str]:
    """Leftovers after up to ``limit_s`` (LinuxCNC's own shutdown takes a few seconds)."""
    deadline = time.monotonic() + limit_s
    while (left := leftovers()) and time.monotonic() < deadline:
        time.sleep(0.2)
    return left


def twin(*args: str, **kwargs) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen(
        [sys.executable, "-m", "gantry_twin", *args], cwd=ROOT, env=env, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True, **kwargs,
    )  # fmt: skip


def stop(process: subprocess.Popen) -> None:
    """The test's end, passed or failed: the twin killed (LinuxCNC then ends by itself) and nothing left."""
    if process.poll() is None:
        process.kill()
        process.wait(30)
    assert wait_until_clean() == [], "LinuxCNC left behind"


# ---------------------------------------------------------------------------------------------- configuration


def test_the_config_holds_the_twin_machine_limits_and_reads_back(tmp_path):
    for name, text in config_files(twin_machine()).items():
        (tmp_path / name).write_text(text)
    machine = machine_from_ini(tmp_path / INI_NAME)
    limits = default_limits()
    assert machine.acceleration_mm_s2 == pytest.approx(tuple(1e3 * a for a in limits.acceleration_m_s2), rel=1e-5)
    assert machine.velocity_mm_s == pytest.approx(tuple(1e3 * v for v in limits.velocity_m_s), rel=1e-5)
    half_mm = 1e3 * (TRAVEL_HALF_M[0] - TRAVEL_MARGIN_M)
    assert machine.travel_mm == ((-half_mm, half_mm), (-half_mm, half_mm))
    assert machine.servo_period_ns == 1_000_000
    ini = (tmp_path / INI_NAME).read_text()
    assert "KINEMATICS = trivkins coordinates=XYZ" in ini and "COORDINATES = X Y Z" in ini
    assert "HOME_SEARCH_VEL = 0" in ini  # the twin's machine homes where it stands: the travel's centre


@pytest.mark.parametrize(
    ("section", "key", "value", "named"),
    [
        ("AXIS_X", "MAX_ACCELERATION", "90000", "[AXIS_X] MAX_ACCELERATION"),
        ("JOINT_1", "MAX_ACCELERATION", "25000", "[JOINT_1] MAX_ACCELERATION"),
        ("AXIS_Y", "MAX_LIMIT", "300", "[AXIS_Y] MAX_LIMIT"),
        ("AXIS_X", "MIN_LIMIT", "-260", "[AXIS_X] MIN_LIMIT"),
        ("EMCMOT", "SERVO_PERIOD", "250000", "[EMCMOT] SERVO_PERIOD"),
        ("KINS", "KINEMATICS", "corexykins", "[KINS] KINEMATICS"),
        ("TRAJ", "LINEAR_UNITS", "furlong", "[TRAJ] LINEAR_UNITS"),
        ("AXIS_X", "MAX_VELOCITY", "fast", "[AXIS_X] MAX_VELOCITY"),
    ],
)
def test_a_users_ini_with_limits_the_twin_cannot_follow_is_refused_naming_the_key(tmp_path, section, key, value, named):
    ini = tmp_path / "machine.ini"
    ini.write_text(f"[{section}]\n{key} = {value}\n")
    with pytest.raises(CncConfigError) as caught:
        machine_from_ini(ini)
    message = str(caught.value)
    assert named in message and str(ini) in message and "\n" not in message


def test_the_followable_acceleration_is_the_peak_force_over_the_mass():
    # The plant in volts (docs/equations.md): M x'' + B x' + Af sgn(x') = u; at rest, 10 V gives (10 - Af) / M.
    speed, accel = followable(0)
    assert accel == pytest.approx(1e3 * (10.0 - 0.1) / 0.12)
    assert speed == pytest.approx(1e3 * (10.0 - 0.1) / 0.5)


def test_an_inch_ini_is_read_in_mm(tmp_path):
    ini = tmp_path / "inch.ini"
    ini.write_text("[TRAJ]\nLINEAR_UNITS = inch\n[AXIS_X]\nMAX_ACCELERATION = 100\nMAX_LIMIT = 5\n")
    machine = machine_from_ini(ini)
    assert machine.acceleration_mm_s2[0] == pytest.approx(2540.0)
    assert machine.travel_mm[0][1] == pytest.approx(127.0)


# ---------------------------------------------------------------------------------------------- the reference


def _corner_record() -> CncRecord:
    """A synthetic record: rest, a line along X with a trapezoidal speed, a stop, a full circle, rest."""
    period = 1e-3
    line = [Move("line", (0.0, 0.0), (0.02, 0.0), 0.1, False, 1)]
    circle = [Move("arc", (0.02, 0.0), (0.02, 0.0), 0.1, False, 2, centre_m=(0.02, 0.01), sweep_rad=2 * math.pi)]
    u_line = 0.02 * (1 - np.cos(np.linspace(0, np.pi, 400))) / 2  # from rest to rest
    theta = -np.pi / 2 + 2 * np.pi * (1 - np.cos(np.linspace(0, np.pi, 800))) / 2
    q = np.vstack([
        np.zeros((5, 2)), np.column_stack([u_line, np.zeros_like(u_line)]),
        np.column_stack([0.02 + 0.01 * np.cos(theta), 0.01 + 0.01 * np.sin(theta)]), np.tile([0.02, 0.0], (5, 1)),
    ])  # fmt: skip
    canon = type("Canon", (), {"moves": line + circle, "items": tuple(line + circle), "messages": (),
                               "unjudged": frozenset(), "splines": 0, "name": "synthetic"})()  # fmt: skip
    t = np.arange(len(q)) * period
    return CncRecord(t, q, np.zeros(len(q), dtype=np.int64), period, float(t[-1]), (), canon, twin_machine())


def test_each_sample_is_attributed_to_its_move_and_a_full_circle_to_itself():
    record = _corner_record()
    move = attribute(MoveTable(list(record.canon.moves)), record.q_m)
    assert np.all(np.diff(move) >= 0)
    assert np.all(move[: 5 + 399] == 0)  # the line, and the rest before it
    assert np.all(move[5 + 400 :] == 1)  # the circle, which ends where it began (the junction may go to either)


def test_a_move_that_retraces_the_one_before_is_told_from_it():
    # Up 10 mm, back down (LinuxCNC stops at the reversal), then right: each sample on its own move.
    moves = [Move("line", (0.0, 0.0), (0.0, 0.01), 0.1, False, 1), Move("line", (0.0, 0.01), (0.0, 0.0), 0.1, False, 2),
             Move("line", (0.0, 0.0), (0.01, 0.0), 0.1, False, 3)]  # fmt: skip
    u = 0.01 * (1 - np.cos(np.linspace(0, np.pi, 100))) / 2
    zeros = np.zeros_like(u)
    q = np.vstack([np.column_stack([zeros, u]), np.column_stack([zeros, u[::-1]]), np.column_stack([u, zeros])])
    move = attribute(MoveTable(moves), q)
    assert list(move[[10, 90, 110, 190, 210, 290]]) == [0, 0, 1, 1, 2, 2]


def test_the_reference_passes_through_every_command_and_its_rates_are_its_derivatives():
    record = _corner_record()
    path = CncPath(record)
    s = path.sample(record.t_s)
    assert np.max(np.abs(s.q_m - record.q_m)) <= 1e-15
    t = np.arange(3.7e-4, path.duration_s, 2e-4)  # never within 1 us of a command (the jerk steps there)
    fine = path.sample(t)
    # Independent: central differences of the interpolated position give its velocity and acceleration.
    h = 1e-6
    ahead, behind = path.sample(t[1:-1] + h), path.sample(t[1:-1] - h)
    v_fd = (ahead.q_m - behind.q_m) / (2 * h)
    a_fd = (ahead.v_m_s - behind.v_m_s) / (2 * h)
    assert np.max(np.abs(v_fd - fine.v_m_s[1:-1])) < 1e-6
    assert np.max(np.abs(a_fd - fine.a_m_s2[1:-1])) < 1e-5
    # alpha on the circle is the tangent's direction, continuous; its rate is the curvature times the speed.
    on_circle = (t > 0.45) & (t < 1.15)
    speed = np.linalg.norm(fine.v_m_s[on_circle], axis=1)
    assert np.max(np.abs(np.diff(fine.alpha_rad[on_circle]))) < 0.05
    assert fine.dalpha_rad_s[on_circle] == pytest.approx(speed / 0.01, rel=2e-2, abs=1e-2)


def test_a_runs_files_give_back_its_record_and_a_file_of_another_kind_is_refused_in_one_line(tmp_path):
    record = _corner_record()
    record = dataclasses.replace(record, line=np.arange(len(record.t_s)) % 3, messages=("M0 pause",))
    written = CncPath(record).run_files()
    for name, text in written.items():
        (tmp_path / name).write_text(text)
    back = read_run_files(tmp_path, record.canon)
    assert np.max(np.abs(back.q_m - record.q_m)) <= 0.5e-9 and np.max(np.abs(back.t_s - record.t_s)) <= 0.5e-6
    assert np.array_equal(back.line, record.line) and back.messages == record.messages
    assert back.machine == record.machine and back.servo_period_s == record.servo_period_s
    info, commands = tmp_path / "linuxcnc.json", tmp_path / "linuxcnc_commands.csv"
    rows = written["linuxcnc_commands.csv"].splitlines()
    cases = [
        (commands, "t_s,x_m,y_m\n0,0,0\n0.001,0,0\n", r"its first line is 't_s,x_m,y_m', not 't_s,x_m,y_m,line'"),
        (commands, "\n".join([rows[0], rows[1], rows[1], *rows[3:]]), r"its times do not increase"),
        (commands, "\n".join(rows[:-1]), r"not 1210 finite rows of 4 columns"),
        (commands, rows[0] + "\n", r"not 1210 finite rows"),  # no numpy warning on the way: -W error says so
        (info, "{}", r"linuxcnc.json: not a run's linuxcnc.json \(KeyError"),
        (info, written["linuxcnc.json"].replace('"servo_period_s": 0.001', '"servo_period_s": 1e400'),
         r"servo_period_s is inf, not a period from 0 to 1 s"),
        (info, written["linuxcnc.json"].replace('"messages": [', '"messages": "abc", "x": ['),
         r"messages is not a list of texts"),
        (info, written["linuxcnc.json"].replace('"canonical_moves": 2', '"canonical_moves": 3'),
         r"synthetic: rs274 reads 2 moves of it now, the run had 3 \(the program changed since the run\)"),
    ]  # fmt: skip
    for path, text, message in cases:
        for name, original in written.items():
            (tmp_path / name).write_text(original)
        path.write_text(text)
        with pytest.raises(ValueError, match=message), warnings.catch_warnings():
            warnings.simplefilter("error")
            read_run_files(tmp_path, record.canon)


# ---------------------------------------------------------------------------------------------- rs274


@needs_rs274
def test_rs274_reads_the_bracket_as_the_twins_reader_does():
    canon = read_canon(ROOT / "programs" / "bracket.ngc")
    own = read_program(ROOT / "programs" / "bracket.ngc").moves
    theirs = canon.moves[1:]  # LinuxCNC starts at the origin: its first move is the rapid to the start
    assert len(theirs) == len(own)
    for a, b in zip(theirs, own, strict=True):
        assert a.kind == b.kind and a.rapid == b.rapid
        # rs274 prints 4 decimals of the program's unit: 0.05 um in mm, 1.27 um in inches (the last hole).
        assert np.allclose(a.end_m, b.end_m, atol=1.3e-6)
        if a.kind == "arc":
            assert np.allclose(a.centre_m, b.centre_m, atol=1.3e-6)
            assert a.sweep_rad == pytest.approx(b.sweep_rad, abs=1e-4)


@needs_rs274
def test_concurrent_rs274_do_not_share_their_tool_table_map():
    # rs274 maps $HOME/.tool.mmap: a dozen at once crashed some with SIGBUS before each got a HOME of its own.
    code = "from gantry_twin.cnc.canon import read_canon; read_canon('programs/bracket.ngc')"
    runs = [subprocess.Popen([sys.executable, "-c", code], cwd=ROOT) for _ in range(8)]
    assert [p.wait(120) for p in runs] == [0] * 8


# ---------------------------------------------------------------------------------------------- LinuxCNC runs


@pytest.fixture
def turn():
    """This test's turn with LinuxCNC (tests/helpers.py: linuxcnc_turn)."""
    with linuxcnc_turn():
        yield


@pytest.fixture(scope="module")
def spline_run(tmp_path_factory):
    """A program the twin's reader refuses (an XZ arc; with G93 and G5.1) run by LinuxCNC and the twin, once."""
    if MISSING is not None:
        pytest.skip(f"LinuxCNC is not installed here: {MISSING}")
    out = tmp_path_factory.mktemp("linuxcnc") / "run"
    with linuxcnc_turn():
        process = twin("run", str(SPLINE_PROGRAM), "--cnc", "linuxcnc", "--out", str(out), "--progress")
        try:
            stdout, stderr = process.communicate(timeout=240)
        finally:
            stop(process)
    return process.returncode, stdout, stderr, out


@needs_linuxcnc
def test_the_twins_reader_refuses_the_program_that_linuxcnc_runs(spline_run):
    done = subprocess.run([sys.executable, "-m", "gantry_twin", "validate", "--drop-unsupported", str(SPLINE_PROGRAM)],
                          capture_output=True, text=True, cwd=ROOT, timeout=120)  # fmt: skip
    assert done.returncode == 2 and "G18" in done.stderr  # another plane: the twin's reader refuses it
    code, stdout, stderr, out = spline_run
    assert code == 0, stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "ok"
    assert summary["part_error"]["dropped"] == {"spline or other-plane moves not judged": 2}
    info = json.loads((out / "linuxcnc.json").read_text())
    assert info["cnc"] == "linuxcnc" and info["splines"] == 1 and info["program_time_s"] > 2.0


@needs_linuxcnc
def test_the_twins_reference_is_linuxcncs_command_at_every_servo_instant(spline_run):
    _, _, _, out = spline_run
    commands = np.loadtxt(out / "linuxcnc_commands.csv", delimiter=",", skiprows=1)
    table = pq.read_table(out / "trace.parquet", columns=["t_s", "x_d_m", "y_d_m"])
    trace = np.column_stack([table.column(name).to_numpy() for name in ("t_s", "x_d_m", "y_d_m")])
    steps = round(1e-3 / 2e-4)
    at_servo = trace[::steps]
    assert len(at_servo) >= len(commands) - 1  # the run's samples end one 0.2 ms step before the last command
    commands = commands[: len(at_servo)]
    assert np.allclose(at_servo[:, 0], commands[:, 0], atol=1e-9)
    assert np.max(np.abs(at_servo[:, 1:] - commands[:, 1:3])) <= 1e-9


@needs_linuxcnc
def test_compares_part_figure_measures_the_run_against_linuxcncs_moves(spline_run, tmp_path):
    """compare draws a LinuxCNC run's part error along LinuxCNC's moves at LinuxCNC's times, rebuilt from the run's
    files: the same error as the run's summary (re-planned by the twin's planner it read 150 mm on the bracket;
    this program the twin's reader refuses). The commands file gives each command's program line."""
    _, _, _, out = spline_run
    run = load_run(str(out), "#1")
    plan, note = program_plan(run)
    assert note is None and isinstance(plan, CncPath)
    table = pq.read_table(out / "trace.parquet", columns=["t_s", "x_m", "y_m"])
    t = table.column("t_s").to_numpy()
    q = np.column_stack([table.column("x_m").to_numpy(), table.column("y_m").to_numpy()])
    distance, _ = nearest_on_program(plan, plan.sample(t).move, q)
    part = json.loads((out / "summary.json").read_text())["part_error"]
    assert np.nanmax(distance) * 1e6 == pytest.approx(part["max_um"], rel=1e-6)
    assert math.sqrt(np.nanmean(distance**2)) * 1e6 == pytest.approx(part["rms_um"], rel=1e-6)
    lines = np.loadtxt(out / "linuxcnc_commands.csv", delimiter=",", skiprows=1)[:, 3]
    assert set(np.unique(lines)) >= {7, 9, 10, 11}  # the G1, G93, G94 and G5.1 lines of the program
    assert main(["compare", str(out), str(out), "--out", str(tmp_path / "cmp")]) == 0
    assert (tmp_path / "cmp" / "plots" / "part.png").is_file()


@needs_linuxcnc
def test_linuxcnc_moves_as_the_program_says(spline_run):
    """Independent of the twin: the program's own numbers. The G93 line (F30: 1/30 min) takes 2 s; the G5.1
    spline is the quadratic B-spline with control points (30, 0), (40, 0), (50, 20) mm, followed within the
    program's blending tolerance (G64 P0.01) on each side; the XZ arc moves X to 60 mm; the program ends at the
    origin (by a subroutine file beside it: LinuxCNC finds it there, as the twin's reader does)."""
    _, _, _, out = spline_run
    commands = np.loadtxt(out / "linuxcnc_commands.csv", delimiter=",", skiprows=1)
    t, q = commands[:, 0], commands[:, 1:3] * 1e3
    on_g93 = (np.abs(q[:, 0] - (q[:, 1] + 20.0)) < 1e-3) & (q[:, 0] > 0.5) & (q[:, 0] < 19.5)
    span = t[on_g93][-1] - t[on_g93][0]
    assert span == pytest.approx(2.0 * 19.0 / 20.0, abs=0.01)  # 95 % of the line's length at its constant speed
    p0, p1, p2 = np.array([30.0, 0.0]), np.array([40.0, 0.0]), np.array([50.0, 20.0])
    u = np.linspace(0.0, 1.0, 20001)[:, None]
    spline = (1 - u) ** 2 * p0 + 2 * u * (1 - u) * p1 + u**2 * p2
    first, last = np.argmin(np.linalg.norm(q - p0, axis=1)), np.argmin(np.linalg.norm(q - p2, axis=1))
    assert last - first > 100
    off = np.min(np.linalg.norm(q[first : last + 1, None, :] - spline[None], axis=2), axis=1)
    assert off.max() < 2 * 0.01
    # The XZ half circle (G18) moves X from 50 to 60 mm at Y 30 (and Z, which the twin ignores).
    assert np.max(q[np.abs(q[:, 1] - 30.0) < 1e-6, 0]) == pytest.approx(60.0, abs=1e-6)
    assert np.allclose(q[-1], 0.0, atol=1e-6)


@needs_linuxcnc
def test_a_program_linuxcnc_refuses_exits_2_with_its_message_and_line(turn, tmp_path):
    bad = tmp_path / "limit.ngc"
    bad.write_text("G21 G90\nG1 X10 Y10 F3000\nG1 X300 Y10\nM2\n")
    process = twin("run", str(bad), "--cnc", "linuxcnc", "--out", str(tmp_path / "run"))
    try:
        _, stderr = process.communicate(timeout=120)
    finally:
        stop(process)
    assert process.returncode == 2
    assert f"{bad}:3: LinuxCNC:" in stderr and "limit" in stderr and len(stderr.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()


LONG_PROGRAM = "G21 G90\nG1 X20 F120\nG1 X0\nG1 X20\nM2\n"  # 30 s


def own(process: subprocess.Popen, name: str) -> list[int]:
    """The pids of this test's twin's LinuxCNC processes called ``name`` (by the session's mark in their
    environment, gantry_twin.cnc.session.MARKER: the twin's pid first)."""
    mark = f"{cnc_session.MARKER}={process.pid}-".encode()
    found = []
    for entry in Path("/proc").iterdir():
        try:
            if entry.name.isdigit() and (entry / "comm").read_text().strip() == name:
                if any(v.startswith(mark) for v in (entry / "environ").read_bytes().split(b"\0")):
                    found.append(int(entry.name))
        except OSError:
            continue
    return found


def _started(process: subprocess.Popen, limit_s: float = 60.0) -> None:
    """Wait until LinuxCNC's motion runs (its rtapi_app exists) for this test's twin."""
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        assert process.poll() is None, process.communicate()[1]
        if own(process, "rtapi_app"):
            time.sleep(2.0)  # homing done, the program running
            return
        time.sleep(0.1)
    raise AssertionError("LinuxCNC did not start")


@needs_linuxcnc
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_signal_stops_linuxcnc_and_leaves_nothing(turn, tmp_path, signum):
    program = tmp_path / "long.ngc"
    program.write_text(LONG_PROGRAM)
    process = twin("run", str(program), "--cnc", "linuxcnc", "--out", str(tmp_path / "run"))
    try:
        _started(process)
        process.send_signal(signum)
        _, stderr = process.communicate(timeout=30)
        assert process.returncode == 128 + signum, stderr
        assert wait_until_clean(5.0) == []
        assert not (tmp_path / "run").exists()
    finally:
        stop(process)


@needs_linuxcnc
@pytest.mark.parametrize("victim", ["rtapi_app", "linuxcnc"])
def test_a_killed_linuxcnc_fails_the_run_in_one_line_and_leaves_nothing(turn, tmp_path, victim):
    program = tmp_path / "long.ngc"
    program.write_text(LONG_PROGRAM)
    process = twin("run", str(program), "--cnc", "linuxcnc", "--out", str(tmp_path / "run"))
    try:
        _started(process)
        victims = own(process, victim)
        assert victims, f"no {victim} of this test's LinuxCNC"
        for pid in victims:
            os.kill(pid, signal.SIGKILL)
        _, stderr = process.communicate(timeout=60)
        assert process.returncode == 1, stderr
        assert stderr.startswith("gantry-twin: run failed:") and len(stderr.strip().splitlines()) == 1
        assert wait_until_clean(5.0) == []
    finally:
        stop(process)


@needs_linuxcnc
def test_a_killed_twin_leaves_nothing_of_linuxcnc(turn, tmp_path):
    program = tmp_path / "long.ngc"
    program.write_text(LONG_PROGRAM)
    process = twin("run", str(program), "--cnc", "linuxcnc", "--out", str(tmp_path / "run"))
    try:
        _started(process)
        process.kill()  # SIGKILL: the twin cleans nothing; LinuxCNC's display sees it and LinuxCNC ends
        process.wait(10)
        assert wait_until_clean(30.0) == []
    finally:
        stop(process)


def test_without_linuxcnc_the_run_says_what_is_missing_in_one_line(tmp_path):
    empty = tmp_path / "bin"
    empty.mkdir()
    done = subprocess.run(
        [sys.executable, "-m", "gantry_twin", "run", str(SPLINE_PROGRAM), "--cnc", "linuxcnc", "--out",
         str(tmp_path / "run")],
        capture_output=True, text=True, cwd=ROOT, timeout=120, env={**os.environ, "PATH": str(empty)},
    )  # fmt: skip
    assert done.returncode == 2
    assert "contour.cnc: linuxcnc: LinuxCNC's 'linuxcnc' is not on PATH" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and not (tmp_path / "run").exists()


@needs_rs274
def test_validate_with_linuxcnc_reads_the_program_as_rs274_does():
    done = subprocess.run([sys.executable, "-m", "gantry_twin", "validate", str(SPLINE_PROGRAM), "--cnc", "linuxcnc"],
                          capture_output=True, text=True, cwd=ROOT, timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr
    # The program's own moves: G0, G1, G93 G1, G1, [G5.1 + G1], [G18 G2 + G0]: two stretches not judged.
    assert "reads 6 XY moves (1 rapid)" in done.stdout and "2 spline or other-plane stretches" in done.stdout
    assert "X -20.000 .. 50.000 mm, Y -20.000 .. 30.000 mm" in done.stdout


# ---------------------------------------------------------------------------------------------- the live mode

DISPLAY = ROOT / "tests" / "data" / "linuxcnc" / "display_live.py"
#: A 2 s program: a line, a half circle, two lines back to the start (F3000: 50 mm/s).
LIVE_PROGRAM = "G21 G90 G64 P0.01\nG1 X20 Y0 F3000\nG3 X20 Y20 I0 J10\nG1 X0 Y20\nG1 X0 Y0\nM2\n"
#: 20 V on X's input from the twin's t = 3 s: twice what the controller can answer, X runs into its end stop.
FAULT_SCENARIO = """description: "live mode: X pushed into its end stop"
contour: {type: circle, radius_m: 0.2, timing: {rate_rad_s: 2.0, start: on_path}}
disturbance:
  x:
    - {type: step, value_v: 10.0, start_s: 3.0}
    - {type: step, value_v: 10.0, start_s: 3.0}
controller: {name: diarc}
"""
LIVE_PROCESSES = {
    "linuxcnc",
    "rtapi_app",
    "milltask",
    "linuxcncsvr",
    "io",
    "halsampler",
    "halstreamer",
    "display_live.py",
}


def live_leftovers(before: dict[int, tuple[int, int]], marker: str) -> list[str]:
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
        if state != "Z" and (name in LIVE_PROCESSES or marker in command):
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
            shutil.copyfile(DISPLAY_SCRIPT, directory / DISPLAY_SCRIPT.name)  # its bring-up: display_offline.py
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
        while (left := live_leftovers(before, marker)) and time.monotonic() < deadline:
            time.sleep(0.2)
    assert left == [], f"the session left {left}"
    return said, run_dir, output


def live_event(events: list[dict], name: str) -> dict:
    found = [e for e in events if e["event"] == name]
    assert found, f"no {name!r} among {[e['event'] for e in events]}: {events[-1] if events else ''}"
    return found[-1]


def live_trace(run_dir: Path) -> dict[str, np.ndarray]:
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


def test_the_live_reference_passes_through_every_command_and_its_rates_are_its_derivatives():
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
    path.write_text(LIVE_PROGRAM)
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
    done = live_event(events, "program_done")
    assert not done["estop"]
    data = live_trace(run_dir)
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
    live, offline = live_trace(run_dir), offline_program
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
    done = live_event(events, "program_done")
    data = live_trace(run_dir)
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
    pins = live_event(events, "pins")
    assert "joint.0.motor-pos-fb <== x-fb" in pins["show"]
    data = live_trace(run_dir)
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
    end = live_event(events, "end")
    assert end["estop"] and not end["enable_in"]
    info = json.loads((run_dir / "linuxcnc_live.json").read_text())
    assert info["ended_by"].startswith("the twin's fault: x touched its end stop")
    log = (run_dir / "linuxcnc_live.log").read_text()
    assert "the twin's fault raises LinuxCNC's estop: x touched its end stop" in log
    data = live_trace(run_dir)
    assert np.max(np.abs(data["x_m"])) > 0.25  # into the end stop's zone, independent of the twin's own check


@needs_linuxcnc
def test_linuxcncs_estop_ends_the_twins_run_cleanly_and_rerun_records_it(tmp_path):
    recording = tmp_path / "live.rrd"
    events, run_dir, _ = run_live(tmp_path, "", 3.0, estop=True, telemetry=f"--save {recording}")
    assert live_event(events, "end")["estop"]
    info = json.loads((run_dir / "linuxcnc_live.json").read_text())
    assert info["ended_by"] == "LinuxCNC's estop (iocontrol.0.user-enable-out fell)"
    assert json.loads((run_dir / "summary.json").read_text())["status"] == "ok"
    # rerun's recording of the twin holds its command of every sample, as its trace parts do
    u_x = scalars(read_rrd(recording), "inputs/u_x_V")[:, 0]
    parts = live_trace(run_dir)
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
    end = live_event(events, "end")
    assert end["estop"] and not end["enable_in"]
    log = (run_dir / "linuxcnc_live.log").read_text()
    assert "the twin's fault raises LinuxCNC's estop: the twin stopped:" in log
    assert len(live_trace(run_dir)["t_s"]) > 0


@needs_linuxcnc
def test_a_killed_twin_puts_linuxcnc_in_estop(tmp_path):
    def kill_the_twin(events: Path) -> None:
        os.kill(_twin_pid(tmp_path / "run", events), signal.SIGKILL)

    events, run_dir, _ = run_live(tmp_path, "", 20.0, during=kill_the_twin)
    end = live_event(events, "end")
    assert end["estop"] and not end["enable_in"]
    assert not (run_dir / "summary.json").exists()
    assert len(live_trace(run_dir)["t_s"]) > 0  # the parts written before the kill are readable


def test_commands_that_cannot_be_matched_to_their_moves_are_not_judged_rather_than_judged_wrongly():
    # The commands run 5 mm beside the programmed line: no attribution puts them within 1 mm of a move, and the
    # part error would report 5 mm that LinuxCNC's planner never commanded (a lathe program in XZ did: 22 mm).
    line = [Move("line", (0.0, 0.0), (0.02, 0.0), 0.1, False, 1)]
    u = 0.02 * (1 - np.cos(np.linspace(0, np.pi, 200))) / 2
    q = np.column_stack([u, np.full_like(u, 0.005)])
    canon = type("Canon", (), {"moves": line, "items": tuple(line), "messages": (), "unjudged": frozenset(),
                               "splines": 0, "name": "beside"})()  # fmt: skip
    t = np.arange(len(q)) * 1e-3
    path = CncPath(CncRecord(t, q, np.zeros(len(q), dtype=np.int64), 1e-3, float(t[-1]), (), canon, twin_machine()))
    assert path.out_of_step_m() == pytest.approx(0.005)
    assert path.rapid.all() and "could not be matched" in next(iter(path.program.dropped))
