"""Work coordinate systems: G54-G59.3, G10 L2 / L20, the G92 family, as LinuxCNC keeps them.

Positions are machine coordinates in metres (the twin's: origin at the
centre of the travel). A program point p in program units becomes the
machine point ``work offset + (p * scale + G92 offset)``: the work offsets
(G54-G59.3, parameters 5221-5389, 20 apart) and the G92 offset (5211-5212,
in force while 5210 is 1) are in the machine's units, mm, as LinuxCNC
keeps them. G10 L2 sets a system's offset (and with R its rotation about
its origin, degrees, parameter 5230 + 20 k: machine = offset + rotated
(program + G92), the order of LinuxCNC's canon), G10 L20 the offset that
makes the current point the given one; G92 the offset that makes it so for all
systems; G92.1 clears it, G92.2 suspends it, G92.3 restores it; G53 moves
in machine coordinates for its line.

Polar coordinates ``@`` (radius) ``^`` (angle, degrees) are about the
program's XY zero in both distance modes, as LinuxCNC's ``find_ends``
reads them: in G90 ``@`` alone keeps the current angle and ``^`` alone the
current radius; in G91 ``@`` adds to the current point's radius and ``^``
to its angle (``G91 G1 @-1 ^10`` repeated is a spiral about the origin),
which is undefined at the origin itself. Arc centres ``I J`` are offsets
from the start (G91.1) or program coordinates (G90.1, both needed).
"""

from __future__ import annotations

import math
from collections.abc import Callable

#: Parameters: G92 in force, its offsets; the current system; the first system's offsets (20 apart; R at +9).
P_G92_ON, P_G92_X, P_SYSTEM, P_SYSTEM_X = 5210, 5211, 5220, 5221


class Offsets:
    """The coordinate-system half of :class:`~gantry_twin.gcode.machine.Machine` (its ``params``, ``position``,
    ``scale_m`` and ``error``)."""

    params: dict[int, float]
    position: tuple[float, float]
    scale_m: float
    incremental: bool
    absolute_centres: bool
    axis_dropped: bool
    rapid_to: Callable[[tuple[float, float], int], None]

    def frame(self) -> tuple[float, float, float, float, float, float]:
        """The system in force: its offset (x, y) m, the G92 offset in force (x, y) m, cos and sin of its
        rotation (G10 R, degrees, parameter 5230 + 20 k)."""
        base = P_SYSTEM_X + 20 * (int(self.params.get(P_SYSTEM, 1)) - 1)
        wx, wy = self.params.get(base, 0.0) * 1e-3, self.params.get(base + 1, 0.0) * 1e-3
        gx = gy = 0.0
        if self.params.get(P_G92_ON, 0.0):
            gx, gy = self.params.get(P_G92_X, 0.0) * 1e-3, self.params.get(P_G92_X + 1, 0.0) * 1e-3
        degrees = self.params.get(base + 9, 0.0)
        if degrees == 0.0:
            return wx, wy, gx, gy, 1.0, 0.0
        angle = math.radians(degrees)
        return wx, wy, gx, gy, math.cos(angle), math.sin(angle)

    def to_machine(self, px: float, py: float) -> tuple[float, float]:
        """Program point (m) -> machine: the G92 offset added, rotated, the system's offset added (LinuxCNC's
        order)."""
        wx, wy, gx, gy, c, s = self.frame()
        x, y = px + gx, py + gy
        return wx + c * x - s * y, wy + s * x + c * y

    def to_program(self, mx: float, my: float) -> tuple[float, float]:
        wx, wy, gx, gy, c, s = self.frame()
        x, y = mx - wx, my - wy
        return c * x + s * y - gx, -s * x + c * y - gy

    def target(self, words: dict[str, float]) -> tuple[float, float]:
        """The block's end point, machine m, from X Y (or @ ^) in the distance mode and system in force."""
        s = self.scale_m
        x, y = self.position
        polar = "@" in words or "^" in words
        if "G53" in words:
            if polar:
                raise self.error("@" if "@" in words else "^", "polar coordinates cannot be used with G53")
            if self.incremental:
                raise self.error("G53", "machine coordinates need G90 (absolute)")
            return (words["X"] * s if "X" in words else x), (words["Y"] * s if "Y" in words else y)
        wx, wy, gx, gy, c, sn = self.frame()
        if sn == 0.0 and not polar:  # unrotated: an axis not given keeps its machine coordinate exactly
            if self.incremental:
                return x + words.get("X", 0.0) * s, y + words.get("Y", 0.0) * s
            return (words["X"] * s + wx + gx if "X" in words else x), (words["Y"] * s + wy + gy if "Y" in words else y)
        px, py = self.to_program(x, y)
        if polar:
            px, py = self.polar(words, px, py)
        elif self.incremental:
            px, py = px + words.get("X", 0.0) * s, py + words.get("Y", 0.0) * s
        else:
            px, py = (words["X"] * s if "X" in words else px), (words["Y"] * s if "Y" in words else py)
        return self.to_machine(px, py)

    def polar(self, words: dict[str, float], px: float, py: float) -> tuple[float, float]:
        """The end of an ``@ ^`` block from the current program point (px, py) m, about the program's zero."""
        word = "@" if "@" in words else "^"
        at_origin = px == 0.0 and py == 0.0
        radius, angle = math.hypot(px, py), math.atan2(py, px)
        if self.incremental:
            if at_origin:
                raise self.error(word, "G91 polar motion is undefined at the XY zero (no angle to add to)")
            radius += words.get("@", 0.0) * self.scale_m
            angle += math.radians(words.get("^", 0.0))
        else:
            if "^" not in words and at_origin:
                raise self.error(word, "at the XY zero polar coordinates need the angle ^")
            radius = words["@"] * self.scale_m if "@" in words else radius
            angle = math.radians(words["^"]) if "^" in words else angle
        return radius * math.cos(angle), radius * math.sin(angle)

    def arc_centre(self, words: dict[str, float]) -> tuple[float, float]:
        """An arc's centre, machine m: I J from the start (G91.1; turned with the system) or, in G90.1,
        program coordinates (both needed)."""
        s = self.scale_m
        if self.absolute_centres:
            for letter in "IJ":
                if letter not in words:
                    raise self.error(letter, "missing: G90.1 (absolute arc centres) needs both I and J")
            return self.to_machine(words["I"] * s, words["J"] * s)
        i, j = words.get("I", 0.0) * s, words.get("J", 0.0) * s
        c, sn = self.frame()[4:]
        return self.position[0] + c * i - sn * j, self.position[1] + sn * i + c * j

    def program_point(self) -> tuple[float, float]:
        """The current point in program coordinates and units (parameters 5420-5421, #<_x> #<_y>)."""
        x, y = self.to_program(*self.position)
        return x / self.scale_m, y / self.scale_m

    def g10(self, words: dict[str, float]) -> None:
        level = words.get("L")
        if level not in (2.0, 20.0):
            raise self.error("G10", "only G10 L2 and G10 L20 (work offsets) are read")
        p = words.get("P", 0.0)
        if p != int(p) or not 0 <= p <= 9:
            raise self.error("P", "G10 needs P0-P9 (0: the system in force, 1-9: G54-G59.3)")
        system = int(p) or int(self.params.get(P_SYSTEM, 1))
        base = P_SYSTEM_X + 20 * (system - 1)
        if "R" in words:
            self.params[base + 9] = words["R"]
        if level == 2.0:
            for axis, letter in enumerate("XY"):
                if letter in words:
                    self.params[base + axis] = words[letter] * self.scale_m * 1e3
            return
        # L20: the offset that makes the current point the given one (the other axis keeps its coordinate)
        current = self.params.get(P_SYSTEM)
        self.params[P_SYSTEM] = float(system)
        px, py = self.to_program(*self.position)
        px = words["X"] * self.scale_m if "X" in words else px
        py = words["Y"] * self.scale_m if "Y" in words else py
        wx, wy, gx, gy, c, s = self.frame()
        x, y = px + gx, py + gy
        self.params[base] = (self.position[0] - (c * x - s * y)) * 1e3
        self.params[base + 1] = (self.position[1] - (s * x + c * y)) * 1e3
        self.params[P_SYSTEM] = current

    def g92(self, words: dict[str, float]) -> None:
        if "G92.1" in words or "G92.2" in words:
            if "G92.1" in words:
                self.params[P_G92_X] = self.params[P_G92_X + 1] = 0.0
            self.params[P_G92_ON] = 0.0
            return
        if "G92.3" in words:
            self.params[P_G92_ON] = 1.0
            return
        if not any(letter in words for letter in "XY"):
            if self.axis_dropped:
                return
            raise self.error("G92", "needs X or Y (the current point's new coordinates)")
        on = self.params.get(P_G92_ON, 0.0)
        old = [self.params.get(P_G92_X + axis, 0.0) if on else 0.0 for axis in (0, 1)]
        self.params[P_G92_ON] = 0.0
        unshifted = self.to_program(*self.position)  # the current point's coordinates without G92, m
        for axis, letter in enumerate("XY"):
            if letter in words:
                self.params[P_G92_X + axis] = (unshifted[axis] - words[letter] * self.scale_m) * 1e3
            else:
                self.params[P_G92_X + axis] = old[axis]
        self.params[P_G92_ON] = 1.0

    def home(self, code: str, words: dict[str, float], number: int) -> None:
        """G28 / G30: a rapid to the X Y given (if any, in the mode in force), then to the stored position
        (parameters 5161-5162 / 5181-5182, machine mm) of the axes given, or of both when none is; G28.1 / G30.1
        store the current point there (LinuxCNC's G28)."""
        base = 5161 if code.startswith("G28") else 5181
        if code.endswith(".1"):
            self.params[base], self.params[base + 1] = self.position[0] * 1e3, self.position[1] * 1e3
            return
        given = ("X" in words, "Y" in words)
        if not any(given) and self.axis_dropped:
            return  # G28 Z0: only a dropped axis goes home
        if any(given):
            self.rapid_to(self.target(words), number)
        stored = (self.params.get(base, 0.0) * 1e-3, self.params.get(base + 1, 0.0) * 1e-3)
        both = not any(given)
        end = tuple(stored[a] if both or given[a] else self.position[a] for a in (0, 1))
        self.rapid_to((end[0], end[1]), number)
