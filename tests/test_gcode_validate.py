"""`gantry-twin validate PROGRAM.ngc`: read and plan without simulating; `--drop-unsupported`; `--subroutine-path`.

The bounds (an endless loop, an endless recursion: exit 2 within 5 s and 300 MB) are hostile-input cases
(tests/test_hostile_input.py, `gcode_endless_loop`, `gcode_endless_recursion`).
"""

from __future__ import annotations

import math

import pytest

from gantry_twin.cli import app as cli
from gantry_twin.gcode import plan_program, read_program
from gantry_twin.gcode.report import fraction_at_feed


def test_validate_reads_and_plans_a_program_and_prints_its_summary(tmp_path, capsys):
    program = tmp_path / "wiggle.ngc"
    lines = "".join(f"X{k} Y{0.001 if k % 2 else -0.001}\n" for k in range(1, 20))
    program.write_text(f"G0 X-10 Y0\nG1 X0 F600\nG64 P0.01 Q0.002\n{lines}X20 Y0\nG0 X-10 Y5\n(msg, done)\nM2\n")
    assert cli.main(["validate", str(program)]) == 0
    out = capsys.readouterr().out.splitlines()
    read = read_program(program)
    plan = plan_program(read)
    assert out[0] == f"{program}: ok ({read.blocks} blocks executed)"
    assert out[1] == "  moves: 3 (2 feed, 1 rapid)"  # 20 wiggling lines merged into one
    assert out[2] == f"  length: 30.000 mm at feed, {math.hypot(30, 5):.3f} mm rapid"
    assert out[3] == f"  planned time: {plan.duration_s:.3f} s"
    assert out[4] == f"  at programmed feed: {100 * fraction_at_feed(plan):.1f} % of the feed moves' time"
    assert out[5:7] == ["  dropped: nothing", "  merged (G64 Q): 19 G1 line(s)"]
    assert out[7] == "  extent X: -10.000 .. 20.000 mm of +-255 mm travel (7.8 % of the half travel)"
    assert out[8] == "  extent Y: 0.000 .. 5.000 mm of +-255 mm travel (2.0 % of the half travel)"
    assert out[9] == f"  {program}:25: msg: done"  # 3 lines, 19 wiggles, X20, G0, then the message


def test_the_fraction_at_feed_is_the_share_of_feed_time_at_the_programmed_speed():
    """Recomputed here on a finer grid (0.1 ms) from the plan's own speed, and the rapid's time left out."""
    import numpy as np

    from gantry_twin.gcode import parse_program

    plan = plan_program(parse_program("G0 X-50\nG1 X100 F6000\nG0 X0 Y50\nG1 Y0 F3000\n", name="l.ngc"))
    t = np.arange(0.0, plan.duration_s, 1e-4)
    s = plan.sample(t)
    feed = np.array([0.0 if m.rapid else m.feed_m_s for m in plan.moves])[s.move]
    rows = feed > 0
    at = np.hypot(s.v_m_s[rows, 0], s.v_m_s[rows, 1]) >= 0.99 * feed[rows]
    assert fraction_at_feed(plan) == pytest.approx(at.mean(), abs=0.01)
    assert 0.3 < at.mean() < 0.99  # the ramps take a share, the cruise the rest


def test_drop_unsupported_is_a_flag_of_run_and_validate(tmp_path, capsys):
    program = tmp_path / "z.ngc"
    program.write_text("G0 X0 Y0 Z5\nG1 X10 F600 Z-1\nM3 S1000\n")
    assert cli.main(["validate", str(program)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"gantry-twin: error: {program}:1:10: Z: Z axis: a two-axis gantry cannot do this "
                   "(--drop-unsupported drops it)"]  # fmt: skip
    assert cli.main(["validate", str(program), "--drop-unsupported"]) == 0
    out = capsys.readouterr().out
    assert "  dropped: Z axis 2, spindle 1" in out  # S is read (G95 uses it)
    parser = cli.build_parser()
    args = parser.parse_args(["run", str(program), "--drop-unsupported", "--subroutine-path", str(tmp_path)])
    assert args.drop_unsupported and args.subroutine_path == [str(tmp_path)]


def test_validate_finds_subroutines_on_the_given_path(tmp_path, capsys):
    (tmp_path / "lib").mkdir()
    (tmp_path / "lib" / "hop.ngc").write_text("o<hop> sub\nG91 G1 X#1 F600\nG90\no<hop> endsub\n")
    program = tmp_path / "main.ngc"
    program.write_text("o<hop> call [3]\no<hop> call [4]\n")
    assert cli.main(["validate", str(program)]) == 2
    assert "o<hop> call: no such subroutine" in capsys.readouterr().err
    assert cli.main(["validate", str(program), "--subroutine-path", str(tmp_path / "lib")]) == 0
    assert "  length: 7.000 mm at feed" in capsys.readouterr().out


def test_a_run_shows_and_keeps_the_programs_messages(tmp_path, capsys):
    import json

    program = tmp_path / "talk.ngc"
    program.write_text("#<w>=20\n(print, width #<w>)\nG1 X#<w> F3000 Z1\n(msg, done)\n")
    out = tmp_path / "r"
    assert cli.main(["run", str(program), "--no-plots", "--out", str(out), "--drop-unsupported"]) == 0
    printed = capsys.readouterr().out
    messages = [f"{program}:2: print: width 20.000000", f"{program}:4: msg: done"]
    assert all(f"  {m}" in printed.splitlines() for m in messages), printed
    assert "  dropped: Z axis 1; merged (G64 Q): 0 G1 line(s)" in printed
    part = json.loads((out / "summary.json").read_text())["part_error"]
    assert part["messages"] == messages and part["dropped"] == {"Z axis": 1} and part["merged"] == 0


def test_a_scenario_gives_work_offsets_a_subroutine_path_and_the_block_bound(tmp_path):
    from gantry_twin.scenario import ScenarioError, build, load_scenario

    (tmp_path / "lib").mkdir()
    (tmp_path / "lib" / "hop.ngc").write_text("o<hop> sub\nG1 X#1 Y0 F600\no<hop> endsub\n")
    (tmp_path / "p.ngc").write_text("G55\no<hop> call [10]\nG54 G1 Y5\n")
    scenario = tmp_path / "s.yaml"
    contour = "{type: gcode, file: p.ngc, subroutine_path: [lib], work_offsets: {G55: [-20, 3]}, max_blocks: %d}"
    scenario.write_text(f"contour: {contour % 100}\n")
    moves = build(load_scenario(scenario), str(scenario)).path.moves
    ends = [(round(m.end_m[0] * 1e3, 9), round(m.end_m[1] * 1e3, 9)) for m in moves]
    assert ends == [(-10, 3), (-10, 5)]  # G55's origin at (-20, 3) mm; G54's at the machine's
    scenario.write_text(f"contour: {contour % 2}\n")
    with pytest.raises(ScenarioError, match=r"p.ngc:2: program: more than 2 blocks executed"):
        build(load_scenario(scenario), str(scenario))


def test_validate_reports_a_program_without_xy_moves_and_run_refuses_it(tmp_path, capsys, monkeypatch):
    """A program that only computes and prints, or only moves Z, is judged (0 moves, exit 0); run has nothing
    to run and says so (exit 2)."""
    program = tmp_path / "compute.ngc"
    program.write_text("#1=[2*3]\n(print, six=#1)\nG0 Z5\nG1 Z-1 F100\nM2\n")
    assert cli.main(["validate", str(program), "--drop-unsupported"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[1] == "  moves: 0 (0 feed, 0 rapid)"
    assert out[3] == "  planned time: 0 s (no XY move to plan)"
    assert out[5] == "  dropped: Z axis 2"
    assert out[-1] == f"  {program}:2: print: six=6.000000"
    monkeypatch.chdir(tmp_path)
    assert cli.main(["run", str(program), "--drop-unsupported"]) == 2
    assert "program: has no moves to run" in capsys.readouterr().err
