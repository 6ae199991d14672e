"""Telemetry: recordings read back headless, no effect on results, sinks and options."""

from __future__ import annotations

import argparse
import os
import re
import signal
import socket
import subprocess
import sys
import urllib.request
from pathlib import Path

import mujoco
import numpy as np
import pytest
import rerun as rr

from gantry_twin import Payload, Plant, TimingLaw, circle, create, simulate
from gantry_twin.cli.telemetry import add_telemetry_arguments, telemetry_observers
from gantry_twin.plant.model import THETA_NAMES
from gantry_twin.telemetry import (
    RealtimePacer,
    RerunObserver,
    TelemetryError,
    gantry_bodies,
    magnified_contour_m,
    theta_entity,
)

from .helpers import FLOAT32_REL, read_rrd, run_main, scalars, trace_column

SRC = Path(__file__).resolve().parents[1] / "src"
#: `gantry-twin run` options for a run of 0.1 s (the metric windows must lie inside it).
SHORT_RUN = ["--set", "duration_s=0.1", "--set", "window_s=[0.05,0.1]", "--set", "estimates_window_s=[0.05,0.1]"]


def run(controller: str = "diarc", duration_s: float = 0.5, payload_kg: float = 5.0, observers=()):
    return simulate(
        Plant(Payload(payload_kg)), circle(), TimingLaw(2.0), create(controller), duration_s, observers=observers
    )


def namespace(**kwargs) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_telemetry_arguments(parser)
    args = parser.parse_args([])
    for key, value in kwargs.items():
        setattr(args, key, value)
    return args


@pytest.fixture(scope="module")
def diarc_recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("rrd") / "diarc.rrd"
    with RerunObserver.to_file(path) as observer:
        trace = run("diarc", observers=[observer])
    return trace, path


def test_recording_holds_every_sample_of_the_trace(diarc_recording):
    trace, path = diarc_recording
    reader = rr.chunk.RrdReader(path)
    assert len(reader.recordings()) == 1  # the layout may be sent more than once (plot ranges widened)
    assert 1 <= len(reader.blueprints()) <= 4
    data = read_rrd(path)
    expected = {
        "errors/contour/eps_c_um",
        "errors/contour/eps_n_um",
        "errors/axial/e_x_um",
        "errors/axial/e_y_um",
        "inputs/u_x_V",
        "inputs/u_y_V",
        "inputs/disturbance_x_V",
        "inputs/disturbance_y_V",
        "estimates/dc_hat_V",
        "estimates/gamma_lambda_max",
        "gantry/y_carriage",
        "gantry/y_carriage/x_carriage",
        "contour_mm/xy/actual_x10000",
        *(f"{theta_entity(name)}/{line}" for name in THETA_NAMES for line in ("estimate", "true")),
    }
    assert expected <= set(data)
    assert theta_entity("M1") == "estimates/M1_V_s2_per_m" and theta_entity("Af2") == "estimates/Af2_V"

    times_ns = np.rint(trace.t_s * 1e9).astype(np.int64)
    eps_c = data["errors/contour/eps_c_um"]
    np.testing.assert_array_equal(eps_c["time_ns"], times_ns)
    np.testing.assert_array_equal(scalars(data, "errors/contour/eps_c_um")[:, 0], trace.eps_c_m * 1e6)
    theta_hat = trace.controller_state["theta_hat"]
    every_fifth = slice(None, None, 5)  # estimates and lambda_max at 1 kHz: every 5th 0.2 ms sample, from the first
    for i, name in enumerate(THETA_NAMES):
        estimate = f"{theta_entity(name)}/estimate"
        np.testing.assert_array_equal(data[estimate]["time_ns"], times_ns[every_fifth])
        np.testing.assert_array_equal(scalars(data, estimate)[:, 0], theta_hat[every_fifth, i])
        true = scalars(data, f"{theta_entity(name)}/true")[:, 0]
        np.testing.assert_array_equal(true, np.full(true.size, trace.true_theta[i]))
        assert data[f"{theta_entity(name)}/true"]["time_ns"][[0, -1]].tolist() == times_ns[[0, -1]].tolist()
    np.testing.assert_array_equal(scalars(data, "estimates/dc_hat_V"), trace.controller_state["dc_hat"])
    np.testing.assert_array_equal(data["estimates/gamma_lambda_max"]["time_ns"], times_ns[every_fifth])
    np.testing.assert_array_equal(
        scalars(data, "estimates/gamma_lambda_max")[:, 0], trace.controller_state["gamma_lambda_max"][every_fifth]
    )
    np.testing.assert_array_equal(scalars(data, "inputs/u_y_V")[:, 0], trace.u_v[:, 1])
    np.testing.assert_array_equal(scalars(data, "errors/axial/e_x_um")[:, 0], trace.e_m[:, 0] * 1e6)


def test_3d_transforms_are_decimated_joint_positions(diarc_recording):
    trace, path = diarc_recording
    data = read_rrd(path)
    carriage = data["gantry/y_carriage/x_carriage"]
    stride = 100  # 50 Hz at 0.2 ms
    np.testing.assert_array_equal(carriage["time_ns"], np.rint(trace.t_s[::stride] * 1e9).astype(np.int64))
    # rerun stores translations as float32 (about 10 nm at 0.2 m: plenty for a picture).
    translation = np.asarray(carriage["Transform3D:translation"], dtype=np.float32).reshape(-1, 3)
    np.testing.assert_array_equal(translation[:, 0], trace.q_m[::stride, 0].astype(np.float32))
    y = np.asarray(data["gantry/y_carriage"]["Transform3D:translation"], dtype=np.float32).reshape(-1, 3)
    np.testing.assert_array_equal(y[:, 1], trace.q_m[::stride, 1].astype(np.float32))
    # A static translation would shadow these temporal ones in the viewer: moving bodies have none.
    static = {
        (chunk.entity_path.lstrip("/"), field.name)
        for chunk in rr.chunk.RrdReader(path).stream().to_chunks()
        if chunk.is_static
        for field in chunk.to_record_batch().schema
    }
    assert ("gantry/base", "Transform3D:translation") in static
    assert ("gantry/y_carriage", "Transform3D:translation") not in static
    assert ("gantry/y_carriage/x_carriage", "Transform3D:translation") not in static


def test_magnified_contour_scales_the_radial_error_of_a_circle():
    path = circle(0.2, (0.01, -0.02))
    rng = np.random.default_rng(3)
    phi = rng.uniform(0, 2 * np.pi, 200)
    radius = 0.2 + rng.uniform(-5e-6, 5e-6, 200)  # um-scale contour errors
    centre = np.array([0.01, -0.02])
    q = centre + radius[:, None] * np.column_stack([np.sin(phi), -np.cos(phi)])
    q_guess_phi = phi + rng.uniform(-0.05, 0.05, 200)  # the desired point lags or leads
    shown = magnified_contour_m(path, q, q_guess_phi, 1000.0)
    shown_radius = np.linalg.norm(shown - centre, axis=1)
    np.testing.assert_allclose(shown_radius - 0.2, 1000.0 * (radius - 0.2), rtol=1e-6, atol=1e-12)
    # Along the error vector: the drawn point stays on the ray from the centre through q.
    a, b = shown - centre, q - centre
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    np.testing.assert_allclose(cross, 0.0, atol=1e-12)


def test_last_magnified_point_is_the_last_sample(diarc_recording):
    trace, path = diarc_recording
    data = read_rrd(path)
    entity = data["contour_mm/xy/actual_x10000"]
    last_row = entity["LineStrips2D:strips"][-1]  # one strip per row
    assert len(last_row) == 1
    last_strip = np.asarray(last_row[0], dtype=float)
    assert entity["time_ns"][-1] == np.rint(trace.t_s[-1] * 1e9)
    radius_error_m = np.linalg.norm(trace.q_m[-1]) - 0.2
    # float32 points in mm: resolution about 2e-5 mm at 200 mm.
    np.testing.assert_allclose(np.linalg.norm(last_strip[-1]) - 200.0, 1e4 * radius_error_m * 1e3, rtol=0, atol=1e-4)
    assert abs(1e4 * radius_error_m * 1e3) > 1e-3  # the check above is not vacuous


def test_telemetry_does_not_change_results(tmp_path):
    plain = run("diarc", duration_s=0.3)
    with RerunObserver.to_file(tmp_path / "x.rrd", flush_interval_s=0.0) as observer:
        watched = run("diarc", duration_s=0.3, observers=[observer, RealtimePacer(1000.0)])
    for name in ("t_s", "q_m", "q_meas_m", "q_d_m", "e_m", "eps_n_m", "eps_c_m", "u_v", "disturbance_v", "true_theta"):
        np.testing.assert_array_equal(getattr(watched, name), getattr(plain, name), err_msg=name)
    assert plain.controller_state.keys() == watched.controller_state.keys()
    for key, value in plain.controller_state.items():
        np.testing.assert_array_equal(watched.controller_state[key], value, err_msg=key)


def test_two_runs_in_one_process_get_separate_recordings(tmp_path):
    traces = {}
    for kg in (0.0, 5.0):
        with RerunObserver.to_file(tmp_path / f"{kg}.rrd") as observer:
            traces[kg] = run("darc", duration_s=0.2, payload_kg=kg, observers=[observer])
    assert rr.get_global_data_recording() is None
    assert not np.array_equal(traces[0.0].eps_c_m, traces[5.0].eps_c_m)
    for kg, trace in traces.items():
        data = read_rrd(tmp_path / f"{kg}.rrd")
        np.testing.assert_array_equal(scalars(data, "errors/contour/eps_c_um")[:, 0], trace.eps_c_m * 1e6)


def test_controllers_without_estimates_have_no_estimate_entities(tmp_path):
    with RerunObserver.to_file(tmp_path / "drc.rrd") as observer:
        run("drc", duration_s=0.2, observers=[observer])
    entities = set(read_rrd(tmp_path / "drc.rrd"))
    assert "errors/contour/eps_c_um" in entities
    assert not any(e.startswith("estimates/") for e in entities)


def test_an_observer_records_one_run(tmp_path):
    with RerunObserver.to_file(tmp_path / "a.rrd") as observer:
        run("drc", duration_s=0.1, observers=[observer])
        with pytest.raises(RuntimeError, match="one run"):
            run("drc", duration_s=0.1, observers=[observer])


def test_gantry_boxes_follow_mujoco_kinematics():
    plant = Plant(Payload(5.0))
    bodies = {b.entity: b for b in gantry_bodies(plant)}
    assert set(bodies) == {
        "gantry/base",
        "gantry/y_carriage",
        "gantry/y_carriage/x_carriage",
        "gantry/y_carriage/x_carriage/payload",
    }
    model, data = plant.model, plant.data
    rng = np.random.default_rng(7)
    for q in rng.uniform(-0.25, 0.25, (5, 2)):
        plant.reset(q, np.zeros(2))
        world = {"gantry": (np.zeros(3), np.eye(3))}
        for entity, body in bodies.items():  # parents first
            parent_pos, parent_rot = world[entity.rsplit("/", 1)[0]]
            rot = np.zeros(9)
            x, y, z, w = body.quat_xyzw
            mujoco.mju_quat2Mat(rot, np.array([w, x, y, z]))
            world[entity] = (parent_pos + parent_rot @ body.translations_m(q)[0], parent_rot @ rot.reshape(3, 3))
            body_id = model.body(entity.rsplit("/", 1)[1]).id
            np.testing.assert_allclose(world[entity][0], data.xpos[body_id], atol=1e-12)
            geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body_id]
            centers = world[entity][0] + body.centers_m @ world[entity][1].T
            np.testing.assert_allclose(centers, data.geom_xpos[geoms], atol=1e-12)
            np.testing.assert_array_equal(body.half_sizes_m, model.geom_size[geoms])


def test_realtime_pacer_sleeps_to_the_wall_clock(monkeypatch):
    import gantry_twin.telemetry.sinks as sinks

    clock = {"now": 100.0}
    sleeps = []
    monkeypatch.setattr(sinks.time, "perf_counter", lambda: clock["now"])
    monkeypatch.setattr(sinks.time, "sleep", sleeps.append)

    class FakeTrace:
        sample_period_s = 0.0002

    pacer = RealtimePacer(2.0)
    pacer.on_start(None, FakeTrace())
    clock["now"] += 0.01  # the first 500 samples (0.1 s simulated) took 10 ms
    pacer.on_chunk(FakeTrace(), 0, 500)
    assert sleeps == [pytest.approx(0.05 - 0.01)]
    clock["now"] += 0.2  # running behind: no sleep
    pacer.on_chunk(FakeTrace(), 500, 1000)
    assert len(sleeps) == 1
    with pytest.raises(ValueError):
        RealtimePacer(0.0)


def test_arguments_default_to_no_telemetry_and_validate():
    parser = argparse.ArgumentParser()
    add_telemetry_arguments(parser)
    args = parser.parse_args([])
    assert args.realtime is None and not args.viewer and not args.serve_web
    assert len(telemetry_observers(args)) == 0
    assert parser.parse_args(["--realtime"]).realtime == 1.0
    assert parser.parse_args(["--realtime", "2.5"]).realtime == 2.5
    pacers = telemetry_observers(parser.parse_args(["--realtime", "3"]))
    assert [type(o) for o in pacers] == [RealtimePacer] and pacers[0].factor == 3.0
    for bad in ("0", "-1", "nan", "fast"):
        with pytest.raises(SystemExit) as exit_info:
            parser.parse_args(["--realtime", bad])
        assert exit_info.value.code == 2


def test_bad_sink_options_are_one_line_errors(tmp_path):
    cases = [
        (namespace(save=tmp_path / "run.txt"), "--save: FILE must end in .rrd"),
        (namespace(save=tmp_path / "missing" / "run.rrd"), "--save: directory"),
        (namespace(connect="http://localhost:9876"), "--connect: URL must look like rerun+http://"),
    ]
    for args, message in cases:
        with pytest.raises(TelemetryError, match=re.escape(message)) as error:
            telemetry_observers(args)
        assert "\n" not in str(error.value)
    assert not (tmp_path / "run.txt").exists()


def test_viewer_without_display_says_so_in_one_line(monkeypatch, capsys, tmp_path):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    with pytest.raises(TelemetryError) as error:
        telemetry_observers(namespace(viewer=True))
    assert "\n" not in str(error.value) and "--serve-web" in str(error.value) and "display" in str(error.value)
    from gantry_twin.cli import app as cli

    out = tmp_path / "out"
    assert cli.main(["run", "no_load_circle", *SHORT_RUN, "--viewer", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--serve-web" in err and "Traceback" not in err
    assert not out.exists()  # checked before anything runs


def test_serve_web_prints_a_url_serves_the_viewer_and_stops_on_ctrl_c(tmp_path):
    env = {**os.environ, "PYTHONPATH": f"{SRC}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    command = [sys.executable, "-m", "gantry_twin.cli", "run", "no_load_circle", *SHORT_RUN, "--controller", "drc"]
    process = subprocess.Popen(
        [*command, "--serve-web", "--out", str(tmp_path / "out"), "--no-progress"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        first = process.stdout.readline()
        match = re.search(r"(http://127\.0\.0\.1:(\d+)/\S*)", first)
        assert match, first
        url, port = match.group(1), int(match.group(2))
        with urllib.request.urlopen(url, timeout=10) as reply:
            assert reply.status == 200
            page = reply.read().decode("utf-8", "replace")
        assert "<html" in page.lower() and "rerun" in page.lower()
        after = [process.stdout.readline()]  # the run's summary, then: the run finished and the server waits
        while after[-1] and "Still serving" not in after[-1] and len(after) < 10:
            after.append(process.stdout.readline())
        assert "Still serving" in after[-1] and "with drc" in after[0], after
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=20) == 0
        assert "Traceback" not in process.stderr.read()
        with socket.socket() as s:
            assert s.connect_ex(("127.0.0.1", port)) != 0  # the viewer server stopped
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()


@pytest.mark.filterwarnings("ignore:RRD file has no footer")  # Ctrl-C ends `rerun --save` before it writes one
def test_connect_streams_every_sample_to_a_running_rerun_server(tmp_path):
    """--connect end to end: `rerun --save` listens on a port; what it receives equals the run's trace."""
    import pyarrow.parquet as pq

    from gantry_twin.cli import app as cli
    from gantry_twin.telemetry import free_port, local_grpc_url, rerun_binary, wait_for_port

    port, received = free_port(), tmp_path / "received.rrd"
    server = subprocess.Popen(
        [rerun_binary(), "--port", str(port), "--save", str(received)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert wait_for_port(port, server, timeout_s=20.0), server.stderr.read()
        url = local_grpc_url(port)
        short = ["--set", "duration_s=0.3", "--set", "window_s=[0.1,0.3]", "--set", "estimates_window_s=[0.2,0.3]"]
        out = tmp_path / "out"
        assert cli.main(["run", "no_load_circle", *short, "--connect", url, "--out", str(out), "--no-progress"]) == 0
        server.send_signal(signal.SIGINT)  # rerun --save writes as it receives; Ctrl-C ends it
        assert server.wait(timeout=20) in (0, -signal.SIGINT)
    finally:
        if server.poll() is None:
            server.kill()
            server.wait()
    table = pq.read_table(out / "trace.parquet")
    data = read_rrd(received)
    eps_c = data["errors/contour/eps_c_um"]
    np.testing.assert_array_equal(eps_c["time_ns"], np.round(table.column("t_s").to_numpy() * 1e9).astype(np.int64))
    eps_c_um = scalars(data, "errors/contour/eps_c_um")[:, 0]
    np.testing.assert_allclose(eps_c_um, trace_column(table, "eps_c_m") * 1e6, rtol=2 * FLOAT32_REL)
    m1 = scalars(data, theta_entity("M1") + "/estimate")[:, 0]  # at 1 kHz
    np.testing.assert_allclose(m1, trace_column(table, "theta_hat_M1")[::5], rtol=2 * FLOAT32_REL)


@pytest.mark.slow
def test_health_alarms_are_events_on_the_timeline(tmp_path):
    """A monitored run records each alarm as a text event at its time, and the excitation per axis."""
    import json

    from gantry_twin.cli import app as cli

    rrd = tmp_path / "pickup.rrd"
    out = tmp_path / "out"
    code = cli.main(
        [
            "monitor",
            "payload_pickup_circle",
            "--set",
            "duration_s=24",
            "--out",
            str(out),
            "--save",
            str(rrd),
            "--no-progress",
        ]
    )
    assert code == 0
    alarms = json.loads((out / "summary.json").read_text())["health"]["alarms"]
    assert alarms, "the pick-up must raise an alarm"
    data = read_rrd(rrd)
    texts = data["health/alarms"]["TextLog:text"]
    assert len(texts) == len(alarms)
    for alarm, text, time_ns in zip(alarms, texts, data["health/alarms"]["time_ns"], strict=True):
        assert alarm["parameter"] in str(text)
        assert time_ns == round(alarm["time_s"] * 1e9)
    assert scalars(data, "health/excitation_V").shape[1] == 2


def test_true_value_line_follows_plant_changes(tmp_path):
    """After a 5 kg pick-up the 'true' line of M1 shows the new mass, not the initial one."""
    from gantry_twin.plant.faults import PayloadChange, PlantChanges

    path = tmp_path / "pickup.rrd"
    changes = PlantChanges(payload_change=(PayloadChange(time_s=0.5, mass_kg=5.0),))
    with RerunObserver.to_file(path) as observer:
        trace = simulate(
            Plant(payload_body=True),
            circle(),
            TimingLaw(2.0),
            create("diarc"),
            1.0,
            observers=[observer],
            changes=changes,
        )
    data = read_rrd(path)
    entity = next(e for e in data if e.startswith("estimates/M1") and e.endswith("/true"))
    true = scalars(data, entity)[:, 0]
    times = data[entity]["time_ns"] * 1e-9
    expected = trace.true_parameters_t()[np.rint(times / trace.sample_period_s).astype(int), 0]
    np.testing.assert_allclose(true, expected)
    assert true[0] == pytest.approx(8.28 / 69) and true[-1] == pytest.approx(13.28 / 69)


def test_save_prints_what_it_wrote_and_its_size(tmp_path, capsys):
    rrd = tmp_path / "short.rrd"
    argv = ["run", "--set", "duration_s=0.5", "--out", str(tmp_path / "r"), "--no-plots", "--save", str(rrd)]
    code, out, _ = run_main([*argv, "--no-progress"], capsys)
    size_mb = rrd.stat().st_size / 1e6
    assert code == 0 and f"recording written to {rrd} ({size_mb:.1f} MB)" in out
