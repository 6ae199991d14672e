"""Part programs: read G-code, plan its feed into a reference, measure the part's error.

:mod:`~gantry_twin.gcode.reader` reads LinuxCNC's dialect (lexer, expressions,
interpreter, machine state and offsets, each a module) into
:mod:`~gantry_twin.gcode.geometry` moves; :mod:`~gantry_twin.gcode.planner`
plans them (1-D profiles of :mod:`~gantry_twin.gcode.profiles`) into a
:class:`~gantry_twin.gcode.sampling.Plan`, the jerk-limited reference the
0.2 ms loop runs; :mod:`~gantry_twin.gcode.part_error` measures a
trajectory against the programmed lines and arcs. Docs: docs/gcode.md.
"""

from gantry_twin.gcode.geometry import Dwell, Move
from gantry_twin.gcode.part_error import BlockError, CornerError, PartError, part_error
from gantry_twin.gcode.planner import AxisLimits, PlanOptions, default_limits, plan_program
from gantry_twin.gcode.reader import GcodeError, Program, parse_program, read_program
from gantry_twin.gcode.sampling import Plan, Samples

__all__ = [
    "AxisLimits",
    "BlockError",
    "CornerError",
    "Dwell",
    "GcodeError",
    "Move",
    "PartError",
    "Plan",
    "PlanOptions",
    "Program",
    "Samples",
    "default_limits",
    "parse_program",
    "part_error",
    "plan_program",
    "read_program",
]
