"""The dashboard of a part program's run: the programmed part drawn, the part error logged; estimates that
summary.json does not trust are titled so."""

from __future__ import annotations

import numpy as np
import pytest
import rerun as rr
import rerun.blueprint as rrb

from gantry_twin import Plant, TimingLaw, create, simulate
from gantry_twin.gcode import parse_program, plan_program
from gantry_twin.telemetry import RerunObserver, theta_entity
from gantry_twin.telemetry.dashboard import PROGRAM_ERROR_MAGNIFICATION, VERDICTS_ENTITY

from .helpers import read_rrd, run_main, scalars
from .test_dashboard import _views
from .test_gcode_planner import distance_to_moves
from .test_part_figures import PART, PART_AND_RAPID


@pytest.fixture(scope="module")
def program_recording(tmp_path_factory):
    """DIARC on the short part, recorded to a file, with every blueprint the observer sent."""
    path = tmp_path_factory.mktemp("rrd") / "part.rrd"
    plan = plan_program(parse_program(PART))
    sent: list[rrb.Blueprint] = []
    observer = RerunObserver.to_file(path)
    send = observer.recording.send_blueprint
    observer.recording.send_blueprint = lambda blueprint, **kwargs: (sent.append(blueprint), send(blueprint, **kwargs))
    trace = simulate(Plant(), plan, TimingLaw(1.0), create("diarc"), plan.duration_s, observers=[observer])
    observer.mark_estimates({"M1": "not trusted: a reason", "B2": "not trusted: another"})
    observer.close()
    return plan, trace, path, sent


def test_the_part_error_is_logged_as_the_distance_to_the_programmed_geometry(program_recording):
    plan, trace, path, _ = program_recording
    data = read_rrd(path)
    part = scalars(data, "errors/contour/part_um")[:, 0]
    np.testing.assert_array_equal(data["errors/contour/part_um"]["time_ns"], np.rint(trace.t_s * 1e9).astype(int))
    brute = distance_to_moves(trace.q_m, [m for m in plan.moves if not m.rapid])
    assert part == pytest.approx(brute * 1e6, abs=1e-3)  # um
    assert part.max() > 1.0  # the machine is off the part somewhere (not a line of zeros)


def test_the_programmed_part_is_drawn_to_scale(program_recording):
    plan, _, path, _ = program_recording
    static = {}
    for chunk in rr.chunk.RrdReader(path).stream().to_chunks():
        if chunk.is_static:
            static.setdefault(chunk.entity_path.lstrip("/"), []).append(chunk.to_record_batch())
    (batch,) = static["contour_mm/xy/programmed"]
    column = next(name for name in batch.schema.names if name.endswith("strips"))
    strips = batch.column(column).to_pylist()[0]
    assert len(strips) == len(plan.moves)
    points = np.array([p for s in strips for p in s])  # mm
    assert distance_to_moves(points * 1e-3, plan.moves) == pytest.approx(0.0, abs=1e-8)  # float32 mm
    assert points[:, 0].min() == pytest.approx(-40.0) and points[:, 1].max() == pytest.approx(60.0, abs=1e-3)


def test_untrusted_estimates_are_marked_in_the_title_and_their_reasons_shown(program_recording):
    _, _, path, sent = program_recording
    first, last = ({str(v.origin): v for v in _views(b.root_container)} for b in (sent[0], sent[-1]))
    titles = {origin: str(v.name) for origin, v in last.items()}
    # The mark comes before the unit: a narrow panel cut "M1 [V/(m/s^2)] (not trusted: ..." to "(not truste".
    assert titles[theta_entity("M1")] == "M1 not trusted [V/(m/s^2)]"
    assert titles[theta_entity("B2")] == "B2 not trusted [V/(m/s)]"
    assert titles[theta_entity("M2")] == "M2 [V/(m/s^2)]"
    # The reasons are in a panel of their own, added once they are known.
    assert VERDICTS_ENTITY in last and VERDICTS_ENTITY not in first
    legends = {}
    for chunk in rr.chunk.RrdReader(path).stream().to_chunks():
        if chunk.is_static and chunk.entity_path.endswith("/estimate"):
            batch = chunk.to_record_batch()
            names = [v for n in batch.schema.names if n.endswith("names") for v in batch.column(n).to_pylist()]
            legends.setdefault(chunk.entity_path.lstrip("/"), []).extend(names)
    assert legends[f"{theta_entity('M1')}/estimate"][-1] == ["M1^ (not trusted)"]  # the last one logged wins
    assert legends[f"{theta_entity('M2')}/estimate"][-1] == ["M2^"]


def test_a_saved_run_marks_the_estimates_summary_json_does_not_trust(tmp_path, capsys):
    rrd = tmp_path / "r.rrd"
    argv = ["run", "--set", "duration_s=0.5", "--out", str(tmp_path / "r"), "--no-plots", "--save", str(rrd)]
    code, _, err = run_main([*argv, "--no-progress"], capsys)
    assert code == 0, err
    from gantry_twin.outputs.summary import RunSummary

    estimates = RunSummary.read(tmp_path / "r" / "summary.json").estimates
    untrusted = [n for n, e in estimates.items() if e.distrust]
    assert untrusted  # a 0.5 s run cannot vouch for every estimate
    texts = []
    for chunk in rr.chunk.RrdReader(rrd).stream().to_chunks():
        if chunk.entity_path == f"/{VERDICTS_ENTITY}":
            batch = chunk.to_record_batch()
            texts += [v for name in batch.schema.names if name.endswith("text") for v in batch.column(name).to_pylist()]
    ((text,),) = texts  # one document, one string
    for name in untrusted:
        assert f"- **{name}**: {estimates[name].distrust}" in text


def test_the_error_plots_are_ranged_to_the_part_not_to_the_rapids(tmp_path):
    """A rapid's positioning error (hundreds of um) left the part's few um a flat line: the contour and axial
    error plots are ranged to the samples of feed moves; the rapid's are drawn, off the scale."""
    from .test_dashboard import _range

    plan = plan_program(parse_program(PART_AND_RAPID))
    sent: list[rrb.Blueprint] = []
    with RerunObserver.to_file(tmp_path / "p.rrd") as observer:
        send = observer.recording.send_blueprint
        observer.recording.send_blueprint = lambda blueprint, **kw: (sent.append(blueprint), send(blueprint, **kw))
        trace = simulate(Plant(), plan, TimingLaw(1.0), create("diarc"), plan.duration_s, observers=[observer])
    rapid = np.array([m.rapid for m in plan.moves])[plan.sample(trace.t_s).move]
    assert rapid.any() and (~rapid).any()
    views = {str(v.origin): v for v in _views(sent[-1].root_container)}
    contour = np.column_stack([trace.eps_c_m, trace.eps_n_m]) * 1e6
    for origin, values in (("errors/contour", contour), ("errors/axial", trace.e_m * 1e6)):
        lo, hi = _range(views[origin])
        assert lo < values[~rapid].min() and values[~rapid].max() < hi, origin
    lo, hi = _range(views["errors/contour"])
    assert contour[rapid].min() < lo or contour[rapid].max() > hi  # the rapid's: off the scale


def test_a_program_is_magnified_less_and_its_rapids_not_at_all(tmp_path):
    # At the circle's 10 000x the bracket's corner errors (tens of um) were drawn a metre off its 400 mm part.
    plan = plan_program(parse_program("G0 X-40 Y-20\nG1 X40 F12000\nG0 X40 Y20\nG1 X-40 F12000\nM30\n"))
    rapid = np.array([m.rapid for m in plan.moves])
    assert rapid.any() and not rapid.all()
    path = tmp_path / "p.rrd"
    with RerunObserver.to_file(path, flush_interval_s=0.0) as observer:
        trace = simulate(Plant(), plan, TimingLaw(1.0), create("diarc"), plan.duration_s, observers=[observer])
    assert observer.error_magnification == PROGRAM_ERROR_MAGNIFICATION
    data = read_rrd(path)
    entity = data[f"contour_mm/xy/actual_x{PROGRAM_ERROR_MAGNIFICATION:g}"]
    # One strip per send; its points are at the contour rate, the last at the send's last sample.
    last = np.array([np.asarray(row[0], dtype=float)[-1] for row in entity["LineStrips2D:strips"]])
    k = np.searchsorted(np.rint(trace.t_s * 1e9), entity["time_ns"])
    on_rapid = rapid[plan.sample(trace.t_s[k]).move]
    assert on_rapid.any() and (~on_rapid).any()
    q_mm = trace.q_m[k] * 1e3
    np.testing.assert_allclose(last[on_rapid], q_mm[on_rapid], atol=1e-3)  # where the machine is (float32 mm)
    off = np.linalg.norm(last[~on_rapid] - q_mm[~on_rapid], axis=1)
    err = distance_to_moves(trace.q_m[k][~on_rapid], plan.moves) * 1e3
    np.testing.assert_allclose(off, (PROGRAM_ERROR_MAGNIFICATION - 1) * err, rtol=1e-3, atol=1e-3)
