"""The modal state of a two-axis machine and one block's words turned into moves (LinuxCNC's dialect).

Positions are machine coordinates in metres (the twin's: origin at the
centre of the travel); the work coordinate systems are
:mod:`~gantry_twin.gcode.offsets`'s. ``@`` ``^`` are polar coordinates
(radius, angle in degrees) about the program's XY zero, cumulative in
G91 (LinuxCNC's). G64 Q merges consecutive collinear-within-Q G1 lines
(the naive CAM detector); G81-G89 drill at each X Y: the rapid there is a
move, the Z part dropped (``drop_unsupported``) and counted. Splines (G5,
G5.1, G5.2 / G5.3) are :mod:`~gantry_twin.gcode.splines`'s. The feed is
F units per minute (G94), F times the spindle speed S per revolution
(G95), or F the inverse of the block's time in minutes (G93).
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from collections.abc import Callable

from gantry_twin.gcode.arcs import MM_PER_INCH, arc_moves
from gantry_twin.gcode.compensation import compensate
from gantry_twin.gcode.feeds import FeedModes
from gantry_twin.gcode.geometry import Dwell, Move
from gantry_twin.gcode.offsets import P_SYSTEM, Offsets
from gantry_twin.gcode.splines import SplineMoves
from gantry_twin.gcode.tools import Tool, tool_for_compensation, write_tool

#: Words a two-axis gantry cannot do, by kind, dropped only on request.
AXES = "ZABCUVW"
DROPPABLE_M = {3: "spindle", 4: "spindle", 5: "spindle", 7: "coolant", 8: "coolant", 9: "coolant"}
#: Modal codes that change nothing on this machine.
NOOP_G = {"G49", "G80", "G97", "G98", "G99", "G17", "G8"}
MOTION = {"G0": 0, "G1": 1, "G2": 2, "G3": 3}
SPLINES = {"G5", "G5.1", "G5.2"}
FEED_MODES = {"G93", "G94", "G95"}
CYCLES = {f"G{n}" for n in range(81, 90)}
#: Motion modes whose axis words are not a plain move's (the fast path of :meth:`Machine.execute` skips them).
NOT_STRAIGHT = frozenset(CYCLES | SPLINES)
#: The letters of a block that only moves (the fast path of :meth:`Machine.execute`).
SIMPLE = frozenset("XYF@^")
#: Distinct lines kept for reuse (a program that loops over the same moves holds each once).
INTERNED = 4096
SYSTEMS = {"G54": 1, "G55": 2, "G56": 3, "G57": 4, "G58": 5, "G59": 6, "G59.1": 7, "G59.2": 8, "G59.3": 9}
COMPENSATION = {"G40", "G41", "G42", "G41.1", "G42.1"}
MODAL_GROUPS = {
    "motion": {"G0", "G1", "G2", "G3", "G80", "G5.3"} | CYCLES | SPLINES,
    "plane": {"G17", "G18", "G19"},
    "units": {"G20", "G21"},
    "distance": {"G90", "G91"},
    "arc distance": {"G90.1", "G91.1"},
    "feed mode": FEED_MODES,
    "path": {"G61", "G61.1", "G64"},
    "coordinate system": set(SYSTEMS),
    "cutter compensation": COMPENSATION,
    "non-modal": {"G4", "G10", "G28", "G28.1", "G30", "G30.1", "G53", "G92", "G92.1", "G92.2", "G92.3"},
}
#: Every G code read (the dialect table in docs/gcode.md is checked against it).
READ_G = set(MOTION) | CYCLES | NOOP_G | set(SYSTEMS) | COMPENSATION | SPLINES | FEED_MODES | {
    "G4", "G10", "G20", "G21", "G28", "G28.1", "G30", "G30.1", "G53", "G61", "G61.1", "G64", "G90", "G91",
    "G92", "G92.1", "G92.2", "G92.3", "G5.3", "G90.1", "G91.1",
}  # fmt: skip
READ_M = {"M0", "M1", "M2", "M30", "M6", "M61", "M70", "M71", "M72", "M73"} | {f"M{n}" for n in DROPPABLE_M}
REFUSED_G = {
    "G18": "only the XY plane (G17) exists on a two-axis gantry",
    "G19": "only the XY plane (G17) exists on a two-axis gantry",
    "G33": "spindle-synchronised motion: the gantry has no spindle",
    "G33.1": "spindle-synchronised motion: the gantry has no spindle",
    "G76": "spindle-synchronised motion (threading): the gantry has no spindle",
    "G7": "lathe diameter mode: the gantry is a mill's XY",
    **{f"G38.{n}": "probing: the twin has no probe input" for n in range(2, 6)},
}


class Machine(Offsets, SplineMoves, FeedModes):
    """Modal state and the moves so far; ``params`` is the interpreter's numbered parameters (mm offsets)."""

    def __init__(
        self,
        params: dict[int, float],
        drop: bool,
        error: Callable[..., Exception],
        check: Callable[[Move], None],
        tools: dict[int, Tool] | None = None,
    ) -> None:
        self.params, self.drop, self.fail, self.check = params, drop, error, check
        self.tools = dict(tools or {})  # the tool table (gantry_twin.gcode.tools), for G41 / G42; G10 L1 writes it
        self.interned: dict[tuple, Move] = {}  # a loop's repeated lines are one object each
        self.items: list[Move | Dwell] = []
        self.programmed: list[Move] = []
        self.dropped: Counter[str] = Counter()
        self.merged = 0
        self.merge = True  # G64 Q merges lines (False: every line kept, as LinuxCNC's interpreter emits them)
        self.position = (0.0, 0.0)
        self.start: tuple[float, float] | None = None
        self.motion: int | str | None = None
        self.scale_m = 1e-3  # G21
        self.incremental = False
        self.absolute_centres = False  # G90.1 (LinuxCNC starts in G91.1)
        self.feed_mode = "G94"
        self.f_word = 0.0  # the last F, program units (G94: per minute, G95: per revolution)
        self.spindle_rpm = 0.0  # the last S (G95's feed per revolution)
        self.nurbs, self.nurbs_order, self.spline_ij = [], 3, (0.0, 0.0)
        self.exact_stop = False  # LinuxCNC starts in G64
        self.tolerance_m = math.inf
        self.naive_m = 0.0  # G64 Q: 0 = no merging
        self.feed_m_s: float | None = None
        self.tool = 0  # T (prepared)
        self.selected = 0  # M6
        self.compensation: tuple[str, float | None, int, int] | None = None  # side, radius, tool, G41 line
        self.compensated: list[Move | Dwell] = []
        self.resume: tuple[float, float] | None = None  # where a run ended by G41 / G42 right after G40 left the tool
        self.chain: list[tuple[float, float]] = []  # the points of the last item's merged G1 lines
        self.column: dict[str, int] = {}
        self.axis_dropped = False
        self.file = ""  # the file whose block runs (the interpreter sets it; a subroutine's may be another)
        self.number = 0

    # -- helpers -------------------------------------------------------------------------------------------
    def error(self, word: str, what: str) -> Exception:
        return self.fail(self.column.get(word, 0), word, what)

    def unsupported(self, word: str, kind: str) -> None:
        if not self.drop:
            raise self.error(word, f"{kind}: a two-axis gantry cannot do this (--drop-unsupported drops it)")
        self.dropped[kind] += 1

    def snapshot(self) -> tuple:
        """The modal state M70 saves and M72 restores."""
        return (self.motion, self.scale_m, self.incremental, self.exact_stop, self.tolerance_m, self.naive_m,
                self.feed_m_s, self.params.get(P_SYSTEM, 1), self.absolute_centres, self.feed_mode)  # fmt: skip

    def restore(self, state: tuple) -> None:
        (self.motion, self.scale_m, self.incremental, self.exact_stop, self.tolerance_m, self.naive_m,
         self.feed_m_s, self.params[P_SYSTEM], self.absolute_centres, self.feed_mode) = state  # fmt: skip

    # -- one block -----------------------------------------------------------------------------------------
    def execute(self, words: dict[str, float], number: int, column: dict[str, int]) -> bool:
        """Execute one block's words (codes 'G1', 'M30' and letters); True when it ends the program."""
        self.column, self.number = column, number
        extra = words.keys() - SIMPLE
        straight = not extra or (len(extra) == 1 and next(iter(extra)) in ("G0", "G1"))
        if straight and self.motion not in NOT_STRAIGHT and self.feed_mode == "G94":
            # the common block: axes and feed only, maybe with G0 / G1
            if extra:
                self.motion = MOTION[next(iter(extra))]
            if ("@" in words or "^" in words) and ("X" in words or "Y" in words):
                raise self.error("@" if "@" in words else "^", "polar (@ ^) and X Y on one line")
            if "F" in words:
                if words["F"] < 0.0:
                    raise self.error("F", "the feed must be >= 0")
                self.f_word = words["F"]
                self.feed_m_s = words["F"] * self.scale_m / 60.0
            if "X" in words or "Y" in words or "@" in words or "^" in words:
                if "P" in words and self.motion not in (2, 3):
                    raise self.error("P", "P only follows G4, G64, G10 or an arc (turns)")
                self.move(words, number)
            return False
        for code in [c for c in words if c[0] == "M"]:
            if code in ("M2", "M30", "M0", "M1", "M6", "M61") or code in ("M70", "M71", "M72", "M73"):
                continue
            kind = DROPPABLE_M.get(int(float(code[1:])))
            if kind is None:
                raise self.error(code, "unsupported M code")
            self.unsupported(code, kind)
            del words[code]
        if "M61" in words:  # LinuxCNC's: the loaded tool is Q, nothing changed (read before a cycle takes Q)
            if "Q" not in words or words["Q"] < 0 or words["Q"] != int(words["Q"]):
                raise self.error("M61", "needs Q, the tool number now loaded (a whole number >= 0)")
            self.selected = int(words["Q"])
        if "S" in words:
            if words["S"] < 0.0:
                raise self.error("S", "the spindle speed must be >= 0")
            self.spindle_rpm = words.pop("S")
        for word, kind in (("G43", "tool length offset"), ("G96", "spindle speed mode"),
                           ("H", "tool length offset"), ("$", "spindle number")):  # fmt: skip
            if word in words:
                self.unsupported(word, kind)
                del words[word]
        explicit = any(c in MOTION or c == "G80" for c in words)  # a new motion mode: no cycle on this line
        modal = self.motion if self.motion in CYCLES and not explicit else None
        cycle = next((c for c in words if c in CYCLES), None) or modal
        axes_words = any(letter in words for letter in "XY@^")
        if cycle is not None and (axes_words or any(c in words for c in CYCLES)):
            for letter in "ZRQ":
                words.pop(letter, None)
            if cycle in ("G82", "G89") or "P" in words:
                words.pop("P", None)
        self.axis_dropped = False
        if "G10" in words and words.get("L") in (1.0, 10.0, 11.0):
            for letter in AXES:
                words.pop(letter, None)  # a tool's offsets: read, not used (no tool length offset in XY)
        for letter in AXES:
            if letter in words:
                self.unsupported(letter, f"{letter} axis")
                del words[letter]
                self.axis_dropped = True  # G53 or G92 with only Z: nothing left to do in XY
        self.check_words(words)
        if "T" in words:
            if words["T"] < 0 or words["T"] != int(words["T"]):
                raise self.error("T", "a tool number is a whole number >= 0")
            self.tool = int(words["T"])
        if "M6" in words:
            self.selected = self.tool
        if "F" in words:
            if words["F"] < 0.0:
                raise self.error("F", "the feed must be >= 0")
        if "G20" in words:
            self.scale_m = MM_PER_INCH * 1e-3
        if "G21" in words:
            self.scale_m = 1e-3
        self.feed_mode = next((c for c in words if c in FEED_MODES), self.feed_mode)
        if "F" in words:
            self.f_word = words["F"]
            self.feed_m_s = words["F"] * self.scale_m / 60.0
        if "G90.1" in words or "G91.1" in words:
            self.absolute_centres = "G90.1" in words
        if "G4" in words:
            if "P" not in words:
                raise self.error("G4", "a dwell needs P (seconds)")
            if words["P"] < 0.0:
                raise self.error("P", "a dwell cannot be negative")
            if words["P"] > 0.0:
                self.emit(Dwell(words["P"], number))
        self.path_mode(words)
        system = next((c for c in words if c in SYSTEMS), None)
        if system is not None:
            self.params[P_SYSTEM] = float(SYSTEMS[system])
        self.compensation_words(words)
        if "G90" in words:
            self.incremental = False
        if "G91" in words:
            self.incremental = True
        if "G10" in words:
            if words.get("L") in (1.0, 10.0, 11.0):
                if "P" not in words or words["P"] < 1 or words["P"] != int(words["P"]):
                    raise self.error("P", "G10 L1 / L10 / L11 need P, the tool number (a whole number >= 1)")
                write_tool(self.tools, int(words["P"]), words, self.scale_m, self.error)
            else:
                self.g10(words)
            return "M2" in words or "M30" in words
        if any(c in words for c in ("G92", "G92.1", "G92.2", "G92.3")):
            self.g92(words)
            if "G92" in words:  # its X Y are the offset's; G92.1 / .2 / .3 leave them to the motion
                return "M2" in words or "M30" in words
        home = next((c for c in ("G28", "G28.1", "G30", "G30.1") if c in words), None)
        if home is not None:
            self.home(home, words, number)
            return "M2" in words or "M30" in words
        motion = next((c for c in words if c in MOTION or c in CYCLES or c in SPLINES), None)
        motion = motion or ("G80" if "G80" in words else None)
        before = self.motion
        if motion is not None:
            if motion != self.motion:
                self.nurbs = []  # a new G5.2 curve
            self.motion = None if motion == "G80" else MOTION.get(motion, motion)
        if "G5.3" in words:
            self.nurbs_end(words, number)
            return "M2" in words or "M30" in words
        uses_p = "G4" in words or "G64" in words or self.motion in SPLINES
        axes = any(letter in words for letter in "XY@^")
        arc_p = self.motion in (2, 3) and (axes or "I" in words or "J" in words)
        if self.motion == "G5.2" and not axes and ("P" in words or "L" in words):
            self.spline(words, number)  # the first control point's weight, the order
            return "M2" in words or "M30" in words
        if "P" in words and not uses_p and not arc_p:
            raise self.error("P", "P only follows G4, G64, G10 or an arc (turns)")
        if not axes and any(letter in words for letter in "IJR"):
            if self.motion in (2, 3, "G5.1") and "R" not in words:
                axes = True  # a full circle: I J without X Y (a G5.1 back to its start)
            else:
                raise self.error(next(c for c in "IJR" if c in words), "needs an arc with X or Y")
        if axes or (self.axis_dropped and self.motion in (0, 1) and self.exit_pending()):
            self.move(words, number)  # a Z-only straight move right after G40 is the exit
        elif "G53" in words and not self.axis_dropped:
            raise self.error("G53", "needs X or Y on its line")
        if self.motion in ("G5", "G5.1"):
            self.motion = before  # LinuxCNC's: a G5 / G5.1 block leaves the motion mode as it was
        return "M2" in words or "M30" in words

    def check_words(self, words: dict[str, float]) -> None:
        refused = next((word for word in words if word in REFUSED_G), None)
        if refused is not None:  # the code's own reason first (G33 K: spindle-synchronised, not a plane)
            raise self.error(refused, REFUSED_G[refused])
        if "K" in words:
            raise self.error("K", "not used in the XY plane (G17): arcs take I and J")
        allowed = set("XYIJRFNPTDLQ@^") | READ_G | READ_M
        for word in words:
            if word not in allowed:
                if word in REFUSED_G:
                    raise self.error(word, REFUSED_G[word])
                if word.startswith("G"):
                    raise self.error(word, "unsupported G code")
                raise self.error(word, "unsupported word")
        spline = self.motion in SPLINES or any(c in words for c in SPLINES)
        if "L" in words and "G10" not in words and not (self.motion in CYCLES or any(c in words for c in CYCLES)):
            if not spline:
                raise self.error("L", "L only follows G10, a drilling cycle (repeats) or G5.2 (the order)")
        if "Q" in words and "G64" not in words and not spline and "G10" not in words and "M61" not in words:
            raise self.error("Q", "Q only follows G64, G5, G10 L1 or M61 (or a drilling cycle's peck)")
        if "D" in words and not any(c in words for c in ("G41", "G42", "G41.1", "G42.1")):
            raise self.error("D", "D only follows G41 / G42 (a tool) or G41.1 / G42.1 (a diameter)")
        if ("@" in words or "^" in words) and ("X" in words or "Y" in words):
            raise self.error("@" if "@" in words else "^", "polar (@ ^) and X Y on one line")

    def path_mode(self, words: dict[str, float]) -> None:
        if "G61" in words or "G61.1" in words or "G64" in words:
            self.chain = []  # a new path mode starts a new chain (LinuxCNC flushes its segments)
        if "G61" in words or "G61.1" in words:
            self.exact_stop, self.tolerance_m, self.naive_m = True, math.inf, 0.0
        if "G64" in words:
            tolerance = words.get("P", 0.0)
            if tolerance < 0.0:
                raise self.error("P", "the G64 tolerance must be >= 0 (P0: no tolerance, as G64 alone)")
            naive = words.get("Q", tolerance)
            if naive < 0.0:
                raise self.error("Q", "the G64 Q tolerance must be >= 0 (Q0: no merging)")
            self.exact_stop = False
            self.tolerance_m = tolerance * self.scale_m if tolerance > 0.0 else math.inf
            self.naive_m = naive * self.scale_m

    def compensation_words(self, words: dict[str, float]) -> None:
        code = next((c for c in words if c in COMPENSATION), None)
        if code is None:
            return
        if code == "G40":
            if self.compensation is not None:
                self.compensation = (*self.compensation[:3], -self.compensation[3])  # ends after the next move
            return
        if self.compensation is not None:
            if self.compensation[3] > 0:
                raise self.error(code, "cutter compensation is already on (G40 first)")
            # G40, then G41 / G42 before a move: LinuxCNC ends the run where the tool is and goes on from there
            offset = self.exit_pending()  # (a run of radius 0, or of no move, left the tool where it was)
            self.finish_compensation()
            self.resume = next((i.end_m for i in reversed(self.items) if isinstance(i, Move)), None) if offset else None
        side = "left" if code.startswith("G41") else "right"
        if code.endswith(".1"):
            if "D" not in words or words["D"] < 0:
                raise self.error(code, "needs D, the tool's diameter (>= 0)")
            self.compensation = (side, 0.5 * words["D"] * self.scale_m, 0, self.number)
            return
        tool = int(words["D"]) if "D" in words else self.selected
        if "D" in words and (words["D"] < 0 or words["D"] != int(words["D"])):
            raise self.error("D", "a tool number is a whole number >= 0")
        if tool == 0:
            raise self.error(code, "no tool: select one (T.. M6) or name it with D")
        self.compensation = (side, None, tool, self.number)

    # -- moves ---------------------------------------------------------------------------------------------
    def move(self, words: dict[str, float], number: int) -> None:
        if self.motion is None:
            raise self.error("X" if "X" in words else "Y", "an axis word without G0, G1, G2, G3 or a cycle in force")
        if self.motion in CYCLES:
            self.drill(words, number)
            return
        if self.motion in SPLINES:
            self.spline(words, number)
            return
        if "G53" in words and self.motion not in (0, 1):
            raise self.error("G53", "machine coordinates only with G0 or G1")
        end = self.target(words)
        rapid = self.motion == 0
        if not self.items and not self.compensated and rapid and self.start is None and self.compensation is None:
            self.start = self.position = end  # the run starts at rest after its first G0
            return
        common = self.feed_common(words, number)
        if self.motion in (0, 1):
            if "I" in words or "J" in words or "R" in words:
                raise self.error("I" if "I" in words else "J" if "J" in words else "R", "only arcs take it")
            if end != self.position or self.exit_pending():
                line = self.line(end, common)
                self.emit(self.timed([line], words)[0] if self.feed_mode == "G93" else line)
            self.position = end
            return
        if self.resume is not None and self.compensation is not None and not self.compensated:
            raise self.error(f"G{self.motion}", "the move just after G40 must be a line (G0 or G1), not an arc "
                             "(G41 / G42 again starts where the tool is)")  # fmt: skip
        centre = self.arc_centre(words) if "R" not in words else None
        moves = arc_moves(words, self.position, end, self.scale_m, self.motion == 3, common, self.error, centre)
        for move in self.timed(moves, words):
            self.emit(move)
        self.position = end

    def line(self, end: tuple[float, float], common: dict) -> Move:
        """The line from the current point to ``end``; the same object for the same line (a loop's repeats)."""
        key = (self.position, end, *common.values())
        move = self.interned.get(key)
        if move is None:
            move = Move("line", self.position, end, **common)
            if len(self.interned) < INTERNED:
                self.interned[key] = move
        return move

    def drill(self, words: dict[str, float], number: int) -> None:
        """A drilling cycle: per hole (L repeats in G91) a rapid to X Y, the Z part dropped and counted."""
        repeats = words.get("L", 1.0)
        if repeats < 1 or repeats != int(repeats):
            raise self.error("L", "a cycle's repeats are a whole number >= 1")
        cycle = str(self.motion)
        for _ in range(int(repeats) if self.incremental else 1):
            self.unsupported(cycle, "drilling cycle (its Z motion)")
            self.rapid_to(self.target(words), number)

    def rapid_to(self, end: tuple[float, float], number: int) -> None:
        """A rapid line to ``end`` (machine m); the program's first one places its start."""
        if self.start is None and not self.items and not self.compensated and self.compensation is None:
            self.start = self.position = end
            return
        if self.start is None:
            self.start = self.position
        if end != self.position or self.exit_pending():
            self.emit(Move("line", self.position, end, math.inf, True, number, self.exact_stop, self.tolerance_m))
        self.position = end

    def exit_pending(self) -> bool:
        """G40 followed a compensated run: the next straight move is its exit, from the tool's offset point to the
        programmed one, even where the program leaves X Y as they are (a Z-only move; LinuxCNC's
        ``convert_cutter_compensation_off`` makes the programmed point the current one when the radius is not 0)."""
        if self.compensation is None or self.compensation[3] > 0:
            return False
        if not any(isinstance(item, Move) for item in self.compensated):
            return False
        _, radius_m, tool, _ = self.compensation
        if radius_m is None:  # the tool's (one missing from the table is refused when the run is placed)
            radius_m = self.tools[tool].radius_m if tool in self.tools else math.inf
        return radius_m != 0.0  # a radius of 0 compensates nothing: LinuxCNC's G40 does nothing then

    def emit(self, item: Move | Dwell) -> None:
        """Append a move or a dwell: into the compensated run while G41 / G42 is on, else merged by G64 Q."""
        if isinstance(item, Move):
            self.check(item)  # a runaway leaves the travel here, not after a million moves
            self.programmed.append(item)
        if self.compensation is not None:
            self.compensated.append(item)
            if self.compensation[3] < 0 and isinstance(item, Move):  # the move after G40 closes the run
                self.finish_compensation(exit_move=True)
            return
        if self.merges(item):
            return
        self.items.append(item)
        self.chain = [item.start_m, item.end_m] if isinstance(item, Move) and item.kind == "line" else []

    def merges(self, item: Move | Dwell) -> bool:
        """The naive CAM detector: the G1 line joins the previous one when every point of the chain stays within
        Q of the line from the chain's start to the new end and the new end goes on forward."""
        if not (
            isinstance(item, Move) and item.kind == "line" and not item.rapid and self.naive_m > 0.0 and self.merge
        ):
            return False
        if not self.chain or not self.items or not isinstance(self.items[-1], Move):
            return False
        last = self.items[-1]
        if last.rapid or last.feed_m_s != item.feed_m_s or last.exact_stop or item.exact_stop:
            return False
        (x0, y0), (x1, y1) = self.chain[0], item.end_m
        length = math.hypot(x1 - x0, y1 - y0)
        if length <= 0.0:
            return False
        ux, uy = (x1 - x0) / length, (y1 - y0) / length
        along = [(px - x0) * ux + (py - y0) * uy for px, py in self.chain[1:]]
        if any(abs(-(px - x0) * uy + (py - y0) * ux) > self.naive_m for px, py in self.chain[1:]):
            return False
        if any(b < a for a, b in zip([0.0, *along], [*along, length], strict=True)):
            return False
        self.items[-1] = Move("line", self.chain[0], item.end_m, item.feed_m_s, False, last.line, False,
                              item.tolerance_m)  # fmt: skip
        self.chain.append(item.end_m)
        self.merged += 1
        return True

    def finish_compensation(self, exit_move: bool = False) -> None:
        """Hand the compensated run to :meth:`compensated_run` and place its tool-centre moves; ``exit_move``:
        its last move is the one after G40 (False: the program ended with compensation on)."""
        assert self.compensation is not None
        side, radius_m, tool, line = self.compensation
        run, self.compensated, self.compensation = self.compensated, [], None
        moves = [item for item in run if isinstance(item, Move)]
        if moves:
            centre = list(self.compensated_run(moves, side, radius_m, tool, abs(line), exit_move))
            if self.resume is not None and centre:  # the entry line starts where the run before ended
                centre[0], self.resume = dataclasses.replace(centre[0], start_m=self.resume), None
            for move in centre:
                self.items.append(move)
                self.chain = []
        self.items.extend(item for item in run if isinstance(item, Dwell))

    def compensated_run(
        self, moves: list[Move], side: str, radius_m: float | None, tool: int, line: int, exit_move: bool
    ) -> list[Move]:
        """The tool-centre path of a G41 / G42 run (:func:`gantry_twin.gcode.compensation.compensate`): ``moves``
        from the entry move (the first after G41 / G42) to the exit move (the first after G40; absent when the
        program ends with compensation on, ``exit_move`` False), ``side`` "left" or "right", ``radius_m`` from
        G41.1 / G42.1's D (None: the radius of ``tool``, G41 / G42's D or the tool M6 selected, from the tool
        table), ``line`` the G41 / G42 line, ``self.file`` its file."""
        code = "G41" if side == "left" else "G42"
        if radius_m is None:
            radius_m = tool_for_compensation(self.tools, None, tool, file=self.file, line=line, code=code).radius_m
        return compensate(moves, side, radius_m, self.file, ends_with_exit=exit_move)
