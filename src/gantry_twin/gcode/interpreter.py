"""The interpreter: parameters, O-word control flow and the call stack over the lines the lexer read.

Parameters (LinuxCNC's overview): numbered ``#1``-``#5601`` (unset reads 0;
5400-5413 and 5420-5428 are read-only: 5400 the tool, 5420-5428 the current
point in program coordinates; #5599, 1 at the start, shows ``(debug, ...)``
messages while it is above 0), named local ``#<name>`` (one set per call level) and
global ``#<_name>`` (an unset named parameter is an error to read), and the
read-only globals in :data:`NAMED_STATE`. The values on a line are all
evaluated first and its parameter settings take effect after the line is
read, as LinuxCNC does: ``#1000=2 X#1000`` moves to the old ``#1000``.

O-words: ``sub`` / ``endsub`` / ``call`` (arguments in ``#1``-``#30``, saved
and restored around the call), ``return`` and ``endsub`` with a value in
``#<_value>``, ``if`` / ``elseif`` / ``else`` / ``endif``, ``while`` /
``endwhile``, ``do`` / ``while``, ``repeat`` / ``endrepeat``, ``break``,
``continue``; a subroutine not in the file is ``NAME.ngc`` on the
subroutine path, then in the program's own directory. M70 / M72 save and
restore the modal state, M71 forgets it, M73 restores it when the
subroutine returns. Execution is bounded: at most ``max_blocks`` blocks and
LinuxCNC's nine levels of nested calls.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from gantry_twin.gcode.blocks import Structure, StructureError, structure
from gantry_twin.gcode.expressions import ReadError
from gantry_twin.gcode.lexer import Line, lex
from gantry_twin.gcode.machine import CYCLES, MODAL_GROUPS, SYSTEMS, Machine
from gantry_twin.gcode.offsets import P_SYSTEM, P_SYSTEM_X
from gantry_twin.gcode.program import TRAVEL_HALF_M, GcodeError, Program, check_move, read_bytes, text_lines
from gantry_twin.gcode.tools import Tool

#: Nested calls below the main program (LinuxCNC's INTERP_SUB_ROUTINE_LEVELS, 10, counts the main program).
MAX_CALL_DEPTH = 9
#: Blocks executed before the run is stopped as endless (settable: ``max_blocks``).
MAX_BLOCKS = 1_000_000
#: Numbered parameters: 1 to this (LinuxCNC's RS274NGC_MAX_PARAMETERS - 1); of them the read-only ones (the tool
#: 5400-5413, the current point 5420-5428: LinuxCNC's _readonly_parameters).
NUMBERED = 5601
READ_ONLY_RANGES = ((5400, 5413), (5420, 5428))
READ_ONLY = frozenset(n for first, last in READ_ONLY_RANGES for n in range(first, last + 1))
#: The parameter that shows (debug, ...) messages while it is above 0 (1 at the start).
DEBUG_FLAG = 5599
SUB_PARAMS = 30
#: Read-only named parameters and what they give.
NAMED_STATE = ("_x", "_y", "_metric", "_imperial", "_absolute", "_incremental", "_coord_system", "_feed",
               "_current_tool", "_selected_tool", "_line", "_call_level", "_motion_mode")  # fmt: skip
_SUBSTITUTE = re.compile(r"#<([^<>]*)>|#(\d+)")
#: The modal groups each G code belongs to (MODAL_GROUPS read the other way, once).
_GROUPS_OF = {code: tuple(g for g, members in MODAL_GROUPS.items() if code in members)
              for members in MODAL_GROUPS.values() for code in members}  # fmt: skip


@dataclass
class Unit:
    """One file's lines and O-word structure."""

    name: str
    lines: list[Line]
    structure: Structure


@dataclass
class Frame:
    unit: Unit
    return_pc: int = 0
    saved: list[float] = field(default_factory=list)
    locals: dict[str, float] = field(default_factory=dict)
    counts: dict[int, int] = field(default_factory=dict)
    modal: tuple | None = None  # M70's
    auto_restore: tuple | None = None  # M73's
    line: int = 0


def load_unit(name: str, data: bytes, block_delete: bool = True) -> Unit:
    lines = []
    for number, text in text_lines(data, name):
        try:
            line = lex(text, number)
        except ReadError as error:
            raise GcodeError(name, number, error.word, error.what, error.column) from None
        if not line.empty or line.block_delete:
            lines.append(line)
    try:
        return Unit(name, lines, structure(lines))
    except StructureError as error:
        raise GcodeError(name, error.line, error.word, error.what, error.column) from None


class Interpreter:
    def __init__(
        self,
        unit: Unit,
        *,
        drop_unsupported: bool = False,
        block_delete: bool = True,
        max_blocks: int = MAX_BLOCKS,
        subroutine_path: tuple[Path, ...] = (),
        work_offsets_mm: dict[int, tuple[float, float]] | None = None,
        travel_half_m: tuple[float, float] = TRAVEL_HALF_M,
        tools: dict[int, Tool] | None = None,
        merge_lines: bool = True,
    ) -> None:
        self.main, self.unit = unit, unit
        self.block_delete, self.max_blocks, self.path = block_delete, max_blocks, subroutine_path
        self.params: dict[int, float] = {P_SYSTEM: 1.0, DEBUG_FLAG: 1.0}
        for system, (x, y) in (work_offsets_mm or {}).items():
            self.params[P_SYSTEM_X + 20 * (system - 1)], self.params[P_SYSTEM_X + 20 * (system - 1) + 1] = x, y
        self.globals: dict[str, float] = {}
        self.frames = [Frame(unit)]
        self.number = 0
        self.machine = Machine(
            self.params,
            drop_unsupported,
            self.error,
            lambda move: check_move(move, travel_half_m, self.unit.name),
            tools,
        )
        self.machine.file = unit.name
        self.machine.merge = merge_lines
        self.messages: list[str] = []
        self.loaded: dict[str, Unit] = {}
        self.blocks = 0

    # -- the scope expressions read --------------------------------------------------------------------------
    def error(self, column: int, word: str, what: str, line: int | None = None) -> GcodeError:
        return GcodeError(self.unit.name, self.number if line is None else line, word, what, column or None)

    def numbered(self, index: float, column: int) -> float:
        value = self.params.get(index)  # a set parameter (1.0 finds 1)
        if value is not None:
            return value
        n = round(index)
        if abs(index - n) > 1e-6 or not 1 <= n <= NUMBERED:
            raise self.error(column, f"#{index:g}", f"no such parameter (numbered parameters are 1 to {NUMBERED})")
        if 5420 <= n <= 5428:
            return self.machine.program_point()[n - 5420] if n <= 5421 else 0.0
        if n == 5400:
            return float(self.machine.selected)
        return self.params.get(n, 0.0)

    def named(self, name: str, column: int) -> float:
        if name.startswith("_"):
            if name in NAMED_STATE:
                return self.state(name)
            if name in self.globals:
                return self.globals[name]
        elif name in self.frames[-1].locals:
            return self.frames[-1].locals[name]
        raise self.error(column, f"#<{name}>", "named parameter not defined (set it first)")

    def exists(self, name: str) -> bool:
        return name in NAMED_STATE or name in (self.globals if name.startswith("_") else self.frames[-1].locals)

    def state(self, name: str) -> float:
        m = self.machine
        metric = m.scale_m == 1e-3
        system = {v: k for k, v in SYSTEMS.items()}[int(self.params.get(P_SYSTEM, 1))]
        motion = m.motion if isinstance(m.motion, int) else float(str(m.motion)[1:]) if m.motion else 80
        return {
            "_x": lambda: m.program_point()[0],
            "_y": lambda: m.program_point()[1],
            "_metric": lambda: float(metric),
            "_imperial": lambda: float(not metric),
            "_absolute": lambda: float(not m.incremental),
            "_incremental": lambda: float(m.incremental),
            "_coord_system": lambda: float(system[1:].replace(".", "")) * (10 if "." not in system else 1),
            "_feed": lambda: 0.0 if m.feed_m_s is None else m.feed_m_s * 60.0 / m.scale_m,
            "_current_tool": lambda: float(m.selected),
            "_selected_tool": lambda: float(m.tool),
            "_line": lambda: float(self.number),
            "_call_level": lambda: float(len(self.frames) - 1),
            "_motion_mode": lambda: float(round(motion * 10)),  # G5.1: 51
        }[name]()

    # -- running -------------------------------------------------------------------------------------------
    def run(self) -> Program:
        pc = 0
        while True:
            lines = self.unit.lines
            if pc >= len(lines):
                break
            line = lines[pc]
            self.number = line.number
            if line.block_delete and self.block_delete:
                pc += 1
                continue
            self.blocks += 1
            if self.blocks > self.max_blocks:
                raise self.error(
                    0, "program", f"more than {self.max_blocks} blocks executed (an endless loop?); "
                    "contour.max_blocks sets the bound",
                )  # fmt: skip
            if line.oword is not None:
                pc = self.oword(line, pc)
                continue
            if self.block(line):
                break
            pc += 1
        m = self.machine
        if m.compensation is not None:
            m.finish_compensation()
        start = m.start if m.start is not None else m.position
        return Program(
            self.main.name, tuple(m.items), start, dict(m.dropped), m.merged, tuple(self.messages),
            tuple(m.programmed), self.blocks,
        )  # fmt: skip

    def block(self, line: Line) -> bool:
        """One line of words and settings; True when it ends the program."""
        if line.constant is not None:  # constant axis and feed words: read once
            return self.machine.execute(dict(line.constant[0]), line.number, line.constant[1])
        if not line.words and not line.messages and self.machine.motion not in CYCLES:
            # parameter settings only: nothing for the machine to do (a modal cycle goes the whole way)
            self.machine.column, self.machine.number = {}, line.number
            self.assign([(self.target(a.target, a.column), a.value if isinstance(a.value, float) else a.value(self))
                         for a in line.assignments])  # fmt: skip
            return False
        words: dict[str, float] = {}
        columns: dict[str, int] = {}
        groups: set[str] = set()
        for word in line.words:
            value = word.value if isinstance(word.value, float) else word.value(self)
            if not math.isfinite(value):
                raise self.error(word.column, word.letter, "not a finite number")
            key = word.letter
            if key in "GM":
                key = _code(key, value)
                if key is None:
                    shown = f"{word.letter}{value:.12g}"
                    raise self.error(word.column, shown[:13] + "..." if len(shown) > 13 else shown,
                                     f"unknown {word.letter} code")  # fmt: skip
                for group in _GROUPS_OF.get(key, ()):
                    if group in groups and group != "non-modal" and not ("G80" in words or key == "G80"):
                        raise self.error(word.column, key, f"a second {group} code on the line")
                    groups.add(group)
                if key in words:
                    raise self.error(word.column, key, "repeated on the line")
            elif key in words:
                raise self.error(word.column, key, "word repeated on the line")
            words[key] = value
            columns[key] = word.column
        settings = [(self.target(a.target, a.column), a.value if isinstance(a.value, float) else a.value(self))
                    for a in line.assignments]  # fmt: skip
        for kind, text in line.messages:
            if kind == "debug" and self.params.get(DEBUG_FLAG, 1.0) <= 0.0:
                continue
            shown = text if kind == "msg" else _SUBSTITUTE.sub(self.substitute, text)
            self.messages.append(f"{self.unit.name}:{line.number}: {kind}: {shown}")
        self.assign(settings)
        self.modal_state(words, columns)
        return self.machine.execute(words, line.number, columns)

    def assign(self, settings: list[tuple[int | str, float]]) -> None:
        """Set the line's parameters, all at once after the line was read (LinuxCNC's after-the-line rule)."""
        for target, value in settings:
            if isinstance(target, str):
                (self.globals if target.startswith("_") else self.frames[-1].locals)[target] = value
            else:
                self.params[target] = value

    def target(self, target, column: int) -> int | str:
        if isinstance(target, str):
            if target in NAMED_STATE:
                raise self.error(column, f"#<{target}>", "a read-only parameter")
            return target
        index = target if isinstance(target, float) else target(self)
        n = round(index)
        if abs(index - n) > 1e-6 or not 1 <= n <= NUMBERED or n in READ_ONLY:
            but = " and ".join(f"{first}-{last}" for first, last in READ_ONLY_RANGES)
            raise self.error(
                column, f"#{index:g}", f"cannot be set (writable parameters are 1 to {NUMBERED}, but {but})"
            )
        return n

    def substitute(self, match: re.Match) -> str:
        try:
            value = self.named(match.group(1).lower(), 0) if match.group(1) is not None else self.numbered(
                float(match.group(2)), 0)  # fmt: skip
        except GcodeError:
            return match.group(0)
        return f"{value:.6f}"

    def modal_state(self, words: dict[str, float], columns: dict[str, int]) -> None:
        frame = self.frames[-1]
        if "M70" in words:
            frame.modal = self.machine.snapshot()
        if "M71" in words:
            frame.modal = None
        if "M72" in words:
            if frame.modal is None:
                raise self.error(columns["M72"], "M72", "no modal state saved (M70 first)")
            self.machine.restore(frame.modal)
        if "M73" in words:
            if len(self.frames) == 1:
                raise self.error(columns["M73"], "M73", "only inside a subroutine (it restores on return)")
            frame.auto_restore = self.machine.snapshot()

    # -- O-words -------------------------------------------------------------------------------------------
    def condition(self, line: Line) -> float:
        value = line.oword.args[0]
        return value if isinstance(value, float) else value(self)

    def oword(self, line: Line, pc: int) -> int:
        word = line.oword
        keyword = word.keyword
        unit, st = self.unit, self.unit.structure
        if keyword == "sub":
            return st.end[pc] + 1  # a definition: skipped where it stands
        if keyword in ("endsub", "return"):
            return self.leave(line)
        if keyword == "call":
            return self.call(line, pc)
        if keyword == "if":
            return pc + 1 if self.condition(line) else self.branch(st.end[pc])
        if keyword in ("elseif", "else"):
            return st.endif[pc] + 1  # the branch before ran: skip the rest
        if keyword == "while":
            if pc in st.closes_do:
                return st.start[pc] + 1 if self.condition(line) else pc + 1
            return pc + 1 if self.condition(line) else st.end[pc] + 1
        if keyword == "endwhile":
            return st.start[pc]
        if keyword == "repeat":
            count = round(self.condition(line))
            self.frames[-1].counts[pc] = count
            return pc + 1 if count > 0 else st.end[pc] + 1
        if keyword == "endrepeat":
            start = st.start[pc]
            counts = self.frames[-1].counts
            counts[start] = counts.get(start, 1) - 1
            return start + 1 if counts[start] > 0 else pc + 1
        if keyword == "break":
            loop = st.start[pc]
            self.frames[-1].counts.pop(loop, None)
            return st.end[loop] + 1
        if keyword == "continue":
            loop = st.start[pc]
            return loop if unit.lines[loop].oword.keyword == "while" else st.end[loop]
        return pc + 1  # do, endif

    def branch(self, i: int) -> int:
        st, lines = self.unit.structure, self.unit.lines
        while True:
            self.number = lines[i].number
            keyword = lines[i].oword.keyword
            if keyword == "elseif":
                if self.condition(lines[i]):
                    return i + 1
                i = st.end[i]
                continue
            return i + 1  # else, endif

    def call(self, line: Line, pc: int) -> int:
        word = line.oword
        args = [a if isinstance(a, float) else a(self) for a in word.args]
        unit, where = self.find(word.label, word.column)
        if len(self.frames) > MAX_CALL_DEPTH:
            what = f"calls nested deeper than {MAX_CALL_DEPTH} levels (LinuxCNC's limit; endless recursion?)"
            raise self.error(word.column, f"{word.label} call", what)
        saved = [self.params.get(n, 0.0) for n in range(1, SUB_PARAMS + 1)]
        for n in range(1, SUB_PARAMS + 1):
            self.params[n] = args[n - 1] if n <= len(args) else 0.0
        self.frames[-1].return_pc = pc + 1
        self.frames.append(Frame(self.unit, saved=saved, line=line.number))  # the caller's unit, for the return
        self.unit = unit
        self.machine.file = unit.name
        return where + 1

    def find(self, label: str, column: int) -> tuple[Unit, int]:
        for unit in (self.unit, self.main):
            if label in unit.structure.subs:
                return unit, unit.structure.subs[label][0]
        searched = ["this file"]
        if label.startswith("o<"):
            name = label[2:-1]
            base = Path(self.main.name).parent
            for directory in (*self.path, base):
                path = directory / f"{name}.ngc"
                searched.append(str(directory))
                if path.is_file():
                    key = str(path)
                    if key not in self.loaded:
                        self.loaded[key] = load_unit(key, read_bytes(path))
                    unit = self.loaded[key]
                    if label not in unit.structure.subs:
                        raise self.error(column, f"{label} call", f"{path} does not define {label} sub")
                    return unit, unit.structure.subs[label][0]
        raise self.error(column, f"{label} call", f"no such subroutine (searched: {', '.join(searched)})")

    def leave(self, line: Line) -> int:
        if len(self.frames) == 1:
            raise self.error(line.oword.column, f"{line.oword.label} {line.oword.keyword}", "not inside a call")
        if line.oword.args:
            self.globals["_value"] = self.condition(line)
            self.globals["_value_returned"] = 1.0
        else:
            self.globals["_value_returned"] = 0.0
        frame = self.frames.pop()
        for n, value in enumerate(frame.saved, start=1):
            self.params[n] = value
        if frame.auto_restore is not None:
            self.machine.restore(frame.auto_restore)
        self.unit = frame.unit
        self.machine.file = frame.unit.name
        return self.frames[-1].return_pc


def _code(letter: str, number: float) -> str | None:
    """'G' 1.0 -> 'G1', 'G' 91.1 -> 'G91.1'; None for a malformed code."""
    if number < 0 or number >= 1000:
        return None
    if number == int(number):
        return f"{letter}{int(number)}"
    tenths = round(number * 10)
    if abs(number * 10 - tenths) > 1e-9:
        return None
    return f"{letter}{tenths // 10}.{tenths % 10}"
