"""A part program's figures and compare: part.png draws the part error that summary.json reports, and
``gantry-twin compare`` of one program under two controllers reports both runs' part errors and draws both."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from matplotlib.collections import LineCollection

from gantry_twin.gcode import parse_program, plan_program, read_program
from gantry_twin.gcode.part_error import nearest_on_program
from gantry_twin.outputs.part_plot import PartBins, fig_part, magnification
from gantry_twin.outputs.plots import FIGURES, pyplot, read_series
from gantry_twin.outputs.summary import RunSummary

from .helpers import run_main
from .test_compare import run_main_plain
from .test_gcode_planner import distance_to_moves

PROGRAMS = Path(__file__).resolve().parents[1] / "programs"
#: A short part (about 1.5 s at F12000): lines, a G64 corner, a half circle, and back.
PART = "G0 X-40 Y-20\nG64 P0.01\nG1 X40 F12000\nG1 Y20\nG3 X-40 Y20 I-40 J0\nG1 Y-20\nM30\n"
#: The same, then a rapid to the middle (the runs' figures hatch it).
PART_AND_RAPID = PART.replace("M30", "G0 X150 Y100\nM30")


@pytest.fixture(scope="module")
def program_runs(tmp_path_factory):
    """The part run with DIARC and with DRC, each into its own directory (with plots)."""
    base = tmp_path_factory.mktemp("part")
    program = base / "part.ngc"
    program.write_text(PART_AND_RAPID)
    dirs = {}
    for controller in ("diarc", "drc"):
        dirs[controller] = base / controller
        code, _, err = run_main_plain(
            ["run", str(program), "--controller", controller, "--out", str(dirs[controller]), "--no-progress"]
        )
        assert code == 0, err
    return program, dirs


def test_nearest_programmed_point_is_on_the_program_at_the_part_error():
    plan = plan_program(read_program(PROGRAMS / "bracket.ngc"))
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0.0, plan.duration_s, 500))
    q = plan.sample(t).q_m + rng.normal(0.0, 0.5e-3, (len(t), 2))
    distance, nearest = nearest_on_program(plan, plan.sample(t).move, q)
    ok = np.isfinite(distance)
    assert ok.sum() > 300 and np.isnan(nearest[~ok]).all()
    feed = [m for m in plan.moves if not m.rapid]
    assert np.linalg.norm(q[ok] - nearest[ok], axis=1) == pytest.approx(distance[ok], abs=1e-12)
    assert distance_to_moves(nearest[ok], feed) == pytest.approx(0.0, abs=1e-9)  # on the programmed geometry


def test_part_bins_keep_the_largest_part_error_of_each_bin():
    plan = plan_program(parse_program(PART))
    t = np.arange(0.0, plan.duration_s, 2e-4)
    rng = np.random.default_rng(5)
    q = plan.sample(t).q_m + rng.normal(0.0, 20e-6, (len(t), 2))
    bins = PartBins(plan, 100)
    bins.block(t[:5000], q[:5000])
    bins.block(t[5000:], q[5000:])
    part = bins.series()
    distance, _ = nearest_on_program(plan, plan.sample(t).move, q)
    per_bin = [np.nanmax(distance[i : i + 100]) for i in range(0, 5000, 100)]
    assert part.distance_m[:50] == pytest.approx(per_bin, rel=1e-12)
    assert np.nanmax(part.distance_m) == np.nanmax(distance)


def test_a_program_run_draws_its_part_with_the_error_summary_json_reports(program_runs):
    program, dirs = program_runs
    run = dirs["diarc"]
    assert sorted(p.name for p in (run / "plots").iterdir()) == sorted([*FIGURES, "part.png"])
    summary = RunSummary.read(run / "summary.json")
    plan = plan_program(read_program(program))
    series = read_series(run, summary, "diarc", plan)
    assert np.nanmax(series.part.distance_m) * 1e6 == pytest.approx(summary.part_error.max_um, rel=1e-9)
    plt = pyplot()
    fig = fig_part(plt, [series], "diarc")
    k = magnification([series.part])
    (collection,) = [c for c in fig.axes[0].collections if isinstance(c, LineCollection)]  # the XY panel's
    assert float(collection.get_array().max()) == pytest.approx(summary.part_error.max_um, rel=1e-9)
    # each drawn segment starts at nearest + k (q - nearest), mm
    drawn = (series.part.nearest_m + k * (series.part.q_m - series.part.nearest_m)) * 1e3
    starts = np.array([s[0] for s in collection.get_segments()])
    assert np.isin(starts.round(9), drawn.round(9)).all()
    text = fig._suptitle.get_text()
    assert f"drawn at p + {k:g} (q - p)" in text and f"magnified {k:g}x" in text
    labels = [t.get_text() for ax in fig.axes for t in ax.texts]
    worst = summary.part_error.worst_corners[0]
    assert f"line {worst.line}: {worst.max_um:.1f} µm" in labels
    plt.close(fig)


def test_every_time_figure_of_a_program_run_hatches_its_rapids(program_runs):
    """eps_c, the axial errors and the commands of a program's run hatch its G0 move, at its times, in each panel;
    a legend names it."""
    from gantry_twin.outputs import plots as runplots

    program, dirs = program_runs
    summary = RunSummary.read(dirs["diarc"] / "summary.json")
    plan = plan_program(read_program(program))
    series = read_series(dirs["diarc"], summary, "diarc", plan)
    (rapid,) = [k for k, m in enumerate(plan.moves) if m.rapid]
    plt = pyplot()
    for draw in (runplots.fig_eps_c, runplots.fig_axial, runplots.fig_commands):
        fig = draw(plt, [series])
        labels = [text.get_text() for legend in fig.legends for text in legend.get_texts()]
        labels += [text.get_text() for ax in fig.axes if ax.get_legend() for text in ax.get_legend().get_texts()]
        assert "rapid (G0) moves (1)" in labels, draw.__name__
        for ax in fig.axes:
            hatched = [p for p in ax.patches if p.get_hatch() == "//"]
            assert len(hatched) == 1, draw.__name__
            span = hatched[0].get_x(), hatched[0].get_x() + hatched[0].get_width()  # an axvspan: a Rectangle
            assert span == pytest.approx((plan.t0_s[rapid], plan.end_s[rapid]))
        plt.close(fig)


def test_a_circle_run_has_no_part_figure(tmp_path, capsys):
    assert fig_part(pyplot(), []) is None


def test_compare_of_one_program_under_two_controllers_reports_both_part_errors(program_runs, tmp_path, capsys):
    _, dirs = program_runs
    out = tmp_path / "cmp"
    code, stdout, err = run_main(["compare", str(dirs["diarc"]), str(dirs["drc"]), "--out", str(out)], capsys)
    assert code == 0, err
    table = json.loads((out / "compare.json").read_text())
    assert table["missing"] == []
    for column, run in zip(table["runs"], (dirs["diarc"], dirs["drc"]), strict=True):
        part = json.loads((run / "summary.json").read_text())["part_error"]
        figures = column["figures"]
        assert figures["part error max, to the programmed geometry (um)"] == part["max_um"]
        assert figures["part error rms (um)"] == part["rms_um"]
        assert figures["cycle time (s)"] == part["cycle_time_s"]
        assert figures["worst corner: part error (um), speed, time"].startswith(
            f"line {part['worst_corners'][0]['line']} ("
        )
    diarc, drc = (c["figures"]["part error max, to the programmed geometry (um)"] for c in table["runs"])
    assert diarc != drc
    assert sorted(p.name for p in (out / "plots").iterdir()) == sorted([*FIGURES, "part.png"])
    assert "| part error rms (um) | " in stdout


def test_compare_of_a_program_run_and_a_circle_run_says_which_is_not_a_program(program_runs, tmp_path, capsys):
    _, dirs = program_runs
    circle = tmp_path / "circle"
    short = ["--set", "duration_s=1", "--set", "window_s=[0.2, 1]", "--set", "estimates_window_s=[0.5, 1]"]
    code, _, err = run_main(["run", "no_load_circle", *short, "--out", str(circle), "--no-progress"], capsys)
    assert code == 0, err
    code, stdout, err = run_main(["compare", str(dirs["diarc"]), str(circle), "--out", str(tmp_path / "c")], capsys)
    assert code == 0, err
    assert "| part error rms (um) | " in stdout and "| - (not a part program) |" in stdout
    assert json.loads((tmp_path / "c" / "compare.json").read_text())["missing"] == []


def test_a_scenario_with_a_relative_program_is_compared_from_anywhere(program_runs, tmp_path, capsys, monkeypatch):
    """The run's scenario.yaml names the program by its absolute path, so compare plans it again from any
    working directory."""
    _, dirs = program_runs
    (tmp_path / "job").mkdir()
    (tmp_path / "job" / "part.ngc").write_text(PART)
    (tmp_path / "job" / "part.yaml").write_text("contour: {type: gcode, file: part.ngc}\n")
    run = tmp_path / "run"
    code, _, err = run_main(["run", str(tmp_path / "job" / "part.yaml"), "--out", str(run), "--no-progress"], capsys)
    assert code == 0, err
    assert f"file: {tmp_path / 'job' / 'part.ngc'}" in (run / "scenario.yaml").read_text()
    monkeypatch.chdir(tmp_path)
    code, _, err = run_main(["compare", str(run), str(dirs["drc"]), "--out", str(tmp_path / "c")], capsys)
    assert code == 0 and "cannot be planned again" not in err, err
    assert (tmp_path / "c" / "plots" / "part.png").is_file()
