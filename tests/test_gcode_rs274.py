"""LinuxCNC's own interpreter as the oracle: the project's programs (tests/data/rs274/, written here from
LinuxCNC's documentation) through ``rs274 -g`` and through the twin's reader give the same XY end points.

Each corner of the dialect has a program: work offsets and G92 with G91, rotation (G10 L2 R), polar in
G90 and G91, arcs by R of both signs and by I J in G91.1 and G90.1 with P turns and ends off the circle,
splines, canned cycles with L, subroutines and loops, cutter compensation with a tool table, an inch
program, the feed modes. rs274 prints the moves in work coordinates and the offsets apart; the
comparison (:mod:`gantry_twin.gcode.oracle`) composes them as LinuxCNC's canon does and walks both paths
within 1 um (3 um in inches). Skipped, with the reason, where rs274 is not installed.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from gantry_twin.gcode import parse_program, read_program
from gantry_twin.gcode.oracle import Point, compare, rs274_available, rs274_path, run_rs274, twin_path
from gantry_twin.gcode.tools import read_tool_table

DATA = Path(__file__).parent / "data" / "rs274"
PROGRAMS = sorted(p.name for p in DATA.glob("*.ngc"))
needs_rs274 = pytest.mark.skipif(
    rs274_available() is None, reason="rs274 (LinuxCNC's interpreter, Debian linuxcnc-uspace) is not installed"
)


def inch_table(tmp_path: Path) -> Path:
    """tools.tbl (mm, the twin's machine units) for rs274, whose standalone machine units are inches."""
    tools = read_tool_table(DATA / "tools.tbl")
    path = tmp_path / "tools_in.tbl"
    path.write_text("".join(f"T{t.number} P{t.pocket} D{t.diameter_m / 0.0254!r}\n" for t in tools.values()))
    return path


def both(name: str, tmp_path: Path):
    """rs274's path and the reader's, for one program of tests/data/rs274."""
    program = DATA / name
    table = DATA / "tools.tbl" if "compensation" in name else None
    code, output = run_rs274(program, inch_table(tmp_path) if table else None)
    oracle = rs274_path(code, output)
    assert oracle.ok, f"rs274 refused {name}: {oracle.message}"
    tools = read_tool_table(table) if table else None
    twin = read_program(program, drop_unsupported=True, tools=tools, merge_lines=False)
    return oracle, twin


def test_the_programs_cover_every_corner_the_issue_lists():
    assert PROGRAMS == ["arcs.ngc", "compensation.ngc", "cycles.ngc", "feeds.ngc", "inch.ngc", "offsets.ngc",
                        "polar.ngc", "rotation.ngc", "splines.ngc", "subroutines.ngc"]  # fmt: skip


@needs_rs274
@pytest.mark.parametrize("name", PROGRAMS)
def test_the_reader_gives_rs274s_xy_end_points(name, tmp_path):
    oracle, twin = both(name, tmp_path)
    assert oracle.xy_plane and not oracle.foreign
    result = compare(oracle.points, twin_path(twin))
    assert result.agreed, f"{name}: {result.disagreement}"
    assert result.matched > 5  # the program moves in XY
    assert result.worst_mm <= 1e-3 if name != "inch.ngc" else result.worst_mm <= 3e-3


@needs_rs274
@pytest.mark.parametrize(
    ("name", "change"),
    [
        ("polar.ngc", lambda s: s.replace("G1 @2 ^30", "G1 @2 ^31")),  # a changed angle
        ("arcs.ngc", lambda s: s.replace("I-10 J0 P3", "I-10 J0 P2")),  # a turn less
        ("arcs.ngc", lambda s: s.replace("G91 G2 X10 Y10 R10", "G91 G2 X10 Y10 R-10")),  # the long way round
        ("rotation.ngc", lambda s: s.replace("R30", "R30.01")),  # the rotation by 0.01 deg: 9 um at 50 mm
    ],
)
def test_the_comparison_sees_a_changed_program(name, change, tmp_path):
    """The oracle can fail: rs274 on the original, the reader on a program changed by a little."""
    oracle, _ = both(name, tmp_path)
    changed = tmp_path / name
    changed.write_text(change((DATA / name).read_text()))
    twin = read_program(changed, drop_unsupported=True, merge_lines=False)
    assert not compare(oracle.points, twin_path(twin)).agreed


def test_the_walk_drops_z_only_motion_and_takes_a_splines_end_from_the_reader():
    rs = (Point("rapid", 0.0, 0.0), Point("line", 10.0, 0.0), Point("line", 10.0, 0.0), Point("spline", None, None),
          Point("line", 20.0, 5.0))  # fmt: skip
    twin = (Point("start", 0.0, 0.0), Point("line", 10.0, 0.0), Point("line", 14.0, 3.0), Point("line", 20.0, 5.0))
    assert compare(rs, twin).agreed
    off = dataclasses.replace(twin[3], x=20.0011)
    result = compare(rs, (*twin[:3], off))
    assert not result.agreed and "(1.1 um)" in result.disagreement
    assert not compare(rs[:3], twin).agreed  # the reader has moves rs274 has not


def test_the_walk_keeps_step_through_moves_at_rs274s_print_resolution():
    """Steps of 0.2-0.35 um (a LinuxCNC planner test of random 1 um lines has them): rs274 prints 0.1 um, so a
    move of the reader's may print as one or as none. The walk pairs them; a real miss still fails."""
    rs = (Point("line", 0.0002, 0.0), Point("line", 0.0012, 0.0), Point("line", 0.0022, 0.0))
    twin = (Point("start", 0.0, 0.0), Point("line", 0.00021, 0.0), Point("line", 0.0012, 0.0),
            Point("line", 0.0022, 0.0))  # fmt: skip
    result = compare(rs, twin)
    assert result.agreed and result.matched == 3 and result.worst_mm < 1e-5
    printed_as_none = (twin[0], dataclasses.replace(twin[1], x=0.0003), *twin[2:])
    assert compare(rs[1:], printed_as_none).agreed
    assert not compare(rs[1:], (twin[0], dataclasses.replace(twin[1], x=0.0005), *twin[2:])).agreed  # 0.5 um
    assert not compare(rs, (*twin[:3], dataclasses.replace(twin[3], x=0.0033))).agreed  # 1.1 um off


def test_the_walk_agrees_on_random_sub_micron_paths_as_rs274_prints_them():
    """Paths of 100-400 random steps of 0.05-1 um and of 0-0.3 um, rs274's side printed as rs274 does (4 decimals
    of mm; a point that prints where the last one did is no motion), and 65 moves of the reader's within 0.3 um
    before a line that rs274 prints alone: the walk agrees with each (an earlier walk crashed on most of the
    0-0.3 um paths and refused the last), and not once one point of the reader's moves 50 um (1.5 um may land
    within 1 um of another point of so fine a path)."""
    rng = np.random.default_rng(45)
    paths = [np.cumsum(rng.uniform(low, high, (n, 1)) * _unit(rng.uniform(0, 2 * np.pi, n)), axis=0)
             for low, high in ((0.05e-3, 1e-3), (0.0, 0.3e-3)) for n in rng.integers(100, 400, 30)]  # fmt: skip
    paths.append(np.array([[1e-4 * (k % 3), 0.0] for k in range(65)] + [[0.05, 0.0]]))
    for xy in paths:
        twin = (Point("start", 0.0, 0.0), *(Point("line", float(x), float(y)) for x, y in xy))
        printed = np.round(xy, 4)
        keep = np.r_[True, np.any(printed[1:] != printed[:-1], axis=1)] & np.any(printed != 0.0, axis=1)
        if len(xy) == 66:
            keep = np.arange(66) == 65  # rs274 printed the 65 short moves as none
        rs = tuple(Point("line", float(x), float(y)) for x, y in printed[keep])
        result = compare(rs, twin)
        assert result.agreed, result.disagreement
        k = len(twin) // 2
        moved = (*twin[:k], dataclasses.replace(twin[k], x=twin[k].x + 0.05), *twin[k + 1 :])
        assert not compare(rs, moved).agreed


def _unit(angle: np.ndarray) -> np.ndarray:
    return np.column_stack([np.cos(angle), np.sin(angle)])


@needs_rs274
@pytest.mark.parametrize("name", ["with space", "x$(false)", "a:b"])
def test_rs274_finds_a_subroutine_file_beside_the_program_whatever_the_directory_is_named(name, tmp_path):
    """LinuxCNC splits SUBROUTINE_PATH at ':' and expands each part with wordexp (a space splits it, $(...) runs):
    the directories reach it linked under plain names, so each of these finds the file (and runs nothing)."""
    here = tmp_path / name
    here.mkdir()
    (here / "side.ngc").write_text("o<side> sub\nG1 X[#1] Y0 F600\no<side> endsub\n")
    (here / "main.ngc").write_text("G0 X0 Y0\no<side> call [20]\nM2\n")
    other = tmp_path / "more subroutines"
    other.mkdir()
    (other / "side.ngc").write_text("o<side> sub\nG1 X[#1 + 1] Y0 F600\no<side> endsub\n")
    for path, x in (((), 20.0), ((other,), 21.0)):  # subroutine_path first, then the program's directory
        oracle = rs274_path(*run_rs274(here / "main.ngc", subroutine_path=path))
        assert oracle.ok, oracle.message
        assert oracle.points[-1].x == pytest.approx(x)
        twin = read_program(here / "main.ngc", subroutine_path=path)
        assert twin.moves[-1].end_m[0] == pytest.approx(x * 1e-3)


@needs_rs274
def test_rs274s_message_is_its_error_not_a_print_before_it(tmp_path):
    program = tmp_path / "p.ngc"
    program.write_text("(print, hello world)\nG2 X5\nM2\n")
    assert rs274_path(*run_rs274(program)).message == "R i j k words all missing for arc (at: G2 X5)"


def test_an_arc_of_a_small_sweep_counts_its_one_turn():
    """rs274's ARC_FEED rotation is +-1 for any arc under a turn; an arc of 0.002 rad (a 0.1 mm chord on a 50 mm
    radius, as a planner test has) counted 0 turns in the reader's path."""
    (arc,) = [p for p in twin_path(parse_program("G0 X0 Y0\nG2 X0.1 Y0 I0.05 J-50 F100\n")) if p.kind == "arc"]
    assert arc.turns == -1


def test_the_studys_tool_table_has_every_tool_linuxcncs_samples_load():
    tools = read_tool_table(Path(__file__).parents[1] / "tools" / "rs274_study.tbl")
    assert set(range(1, 21)) | {99999} == set(tools)


def test_rs274s_offsets_compose_as_linuxcncs_canon():
    """machine = rotate(work + G92, rotation) + G5x, in the units in force when rs274 printed them."""
    output = "\n".join([
        "    1 N..... USE_LENGTH_UNITS(CANON_UNITS_INCHES)",
        "    2 N..... SET_G5X_OFFSET(1, 1.0000, 2.0000, 0.0000, 0.0000, 0.0000, 0.0000)",
        "    3 N..... SET_G92_OFFSET(0.5000, 0.0000, 0.0000, 0.0000, 0.0000, 0.0000)",
        "    4 N..... SET_XY_ROTATION(90.0000)",
        "    5 N..... STRAIGHT_FEED(1.0000, 0.0000, 0.0000, 0.0000, 0.0000, 0.0000)",
    ])  # fmt: skip
    (point,) = rs274_path(0, output).points
    assert (point.x, point.y, point.unit) == (pytest.approx(25.4), pytest.approx(2.0 * 25.4 + 1.5 * 25.4), "in")


@needs_rs274
def test_the_study_tool_classes_each_program_of_a_checkout(tmp_path, capsys):
    """tools/rs274_study.py on a checkout of seven programs: four agree (one calls a subroutine file beside
    it, one compensates with the tool table both read), one is in another plane, one rs274 stops (a
    subroutine file, no program end), one is on the edge (its entry move is exactly the tool's radius: the
    reader refuses it by LinuxCNC's rule, rs274 passes it by rounding and refuses it with the tool 1e-9
    wider); exit 0 (none differs)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("rs274_study", Path(__file__).parents[1] / "tools/rs274_study.py")
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    files = tmp_path / "checkout" / "nc_files"
    files.mkdir(parents=True)
    for name in ("polar.ngc", "rotation.ngc"):
        (files / name).write_text((DATA / name).read_text())
    (files / "xz.ngc").write_text("G18 G0 X0 Z0\nG2 X10 Z0 I5 K0 F100\nM2\n")
    (files / "sub.ngc").write_text("o<sub> sub\nG1 X1 Y2 F1\no<sub> endsub\n")
    (files / "calls.ngc").write_text("G0 X0 Y0\no<sub> call\nG1 X3\nM2\n")
    (files / "comp.ngc").write_text("G20 G90 T1 M6\nG0 X-1 Y-1\nG41 G1 X0 Y0 F10\nX1\nY1\nG40 G0 X2 Y2\nM2\n")
    (files / "edge.ngc").write_text("G20 G90 T1 M6\nG0 X0.0625 Y1\nG41 G1 X0 Y1 F10\nY2\nG40 G0 X1 Y3\nM2\n")
    table = tmp_path / "inch.tbl"
    table.write_text("T1 P1 D0.125 ;1/8 in end mill\n")
    assert study.main([str(tmp_path / "checkout"), "--list", "--tool-table", str(table)]) == 0
    out = capsys.readouterr().out
    assert "7 programs: agree 4, not XY 1, on the edge 1, rs274 stops 1" in out, out
    assert "not XY         nc_files/xz.ngc: arcs in another plane" in out
    assert "agree          nc_files/calls.ngc: 2 points" in out
    assert "on the edge    nc_files/edge.ngc: edge.ngc:3: G41: the entry move is 1.5875 mm long" in out
    assert "rs274 with every tool 1e-09 wider: Length of cutter compensation entry move is not greater" in out


# -- splines: LinuxCNC's own NURBS evaluation, from its preview parser ----------------------------------------------
#: The AXIS preview's parser (LinuxCNC's Python module gcode, the system Python's) samples a spline with the
#: interpreter's own NURBS code at 15 points per control point; rs274 -g prints none of them.
_PREVIEW = """
import json, sys
import gcode

class Canon:
    parameter_file = ""
    def __init__(self): self.points = []
    def __getattr__(self, name): return lambda *args, **kw: None
    def straight_feed(self, *a): self.points.append((a[0] * 25.4, a[1] * 25.4))
    def get_external_length_units(self): return 1 / 25.4
    def get_external_angular_units(self): return 1.0
    def get_axis_mask(self): return 7
    def get_block_delete(self): return True
    def check_abort(self): return False
    def get_tool(self, n): return (n, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0.0, 0.0, 0.0, 0)

canon = Canon()
gcode.parse(sys.argv[1], canon, "G21", "")
print(json.dumps(canon.points))
"""
SYSTEM_PYTHON = Path("/usr/bin/python3")


def _preview_available() -> bool:
    import subprocess

    if not SYSTEM_PYTHON.exists():
        return False
    done = subprocess.run([str(SYSTEM_PYTHON), "-c", "import gcode"], capture_output=True, timeout=60, check=False)
    return done.returncode == 0


needs_preview = pytest.mark.skipif(
    not _preview_available(), reason="LinuxCNC's Python module gcode (Debian linuxcnc-uspace) is not installed"
)

SPLINES = {
    "G5.1 quadratic": ("G5.1 X40 Y0 I20 J30", [(0, 0), (20, 30), (40, 0)], [1, 1, 1], 3, 2e-6),
    "G5 cubic": ("G5 X30 Y10 I0 J20 P-5 Q15", [(0, 0), (0, 20), (25, 25), (30, 10)], [1, 1, 1, 1], 4, 2e-6),
    "G5.2 weighted order 4": (
        "G5.2 X10 Y20 P2 L4\nX30 Y25 P0.5\nX40 Y0 P1\nX60 Y10 P3\nX70 Y-5 P1\nG5.3",
        [(0, 0), (10, 20), (30, 25), (40, 0), (60, 10), (70, -5)],
        [1, 2, 0.5, 1, 3, 1],
        4,
        20e-6,
    ),  # fmt: skip
}


@needs_preview
@pytest.mark.parametrize("case", sorted(SPLINES))
def test_splines_are_linuxcncs_nurbs_point_for_point(case, tmp_path):
    """LinuxCNC's preview points P(u_i), u_i = i umax / (15 (n + 1)): the reader's NURBS gives each to 1e-9 mm,
    and its biarcs (4 samples per control point, as LinuxCNC's canon) pass within 2 um of every one (20 um on
    the sharply weighted NURBS: the biarcs' own error, LinuxCNC's too)."""
    import json
    import subprocess

    import numpy as np

    from gantry_twin.gcode.geometry import MoveTable
    from gantry_twin.gcode.splines import knots, nurbs_points

    block, points, weights, order, within_m = SPLINES[case]
    program = tmp_path / "spline.ngc"
    program.write_text(f"G21 G17 G90\nG0 X0 Y0\nG1 F600\n{block}\nM2\n")
    script = tmp_path / "preview.py"
    script.write_text(_PREVIEW)
    done = subprocess.run([str(SYSTEM_PYTHON), str(script), str(program)], capture_output=True, text=True,
                          timeout=120, check=True, cwd=tmp_path)  # fmt: skip
    control = np.array(points, dtype=float)
    preview = np.array(json.loads(done.stdout))
    ends = np.hypot(*(preview - control[0]).T) < 1e-12, np.hypot(*(preview - control[-1]).T) < 1e-12
    preview = preview[~(ends[0] | ends[1])]  # the points between: u_i = i umax / (15 (n + 1)), i = 1, 2, ...
    knot = knots(len(control), order)
    u = knot[-1] * np.arange(1, len(preview) + 1) / (15 * len(control))
    ours = nurbs_points(u, control, np.array(weights, dtype=float), order, knot)
    assert 15 * len(control) - 2 <= len(preview) <= 15 * len(control) - 1
    assert np.abs(ours - preview).max() < 1e-9
    read = read_program(program)
    table = MoveTable(read.moves)
    k = np.repeat(np.arange(table.count), len(preview))  # every point against every move, exactly
    q = np.tile(preview * 1e-3, (table.count, 1))
    distance = table.distance(k, q).reshape(table.count, len(preview)).min(axis=0)
    assert distance.max() < within_m  # the biarcs' own error: 4 samples a control point, as LinuxCNC's canon
    assert read.moves[-1].end_m == pytest.approx(tuple(control[-1] * 1e-3), abs=1e-15)
