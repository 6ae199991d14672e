"""Part programs: read G-code, plan its feed into a reference, measure the part's error.

:mod:`~gantry_twin.gcode.reader` reads the RS274/NGC subset into
:mod:`~gantry_twin.gcode.geometry` moves; :mod:`~gantry_twin.gcode.planner`
plans them into a jerk-limited reference sampled for the 0.2 ms loop;
:mod:`~gantry_twin.gcode.part_error` measures a trajectory against the
programmed lines and arcs. Docs: docs/gcode.md.
"""

from gantry_twin.gcode.geometry import Dwell, Move
from gantry_twin.gcode.reader import GcodeError, Program, parse_program, read_program

__all__ = ["Dwell", "GcodeError", "Move", "Program", "parse_program", "read_program"]
