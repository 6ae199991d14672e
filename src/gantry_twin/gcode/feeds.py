"""The feed of a block's moves in LinuxCNC's three feed modes (its G-code reference, G93 / G94 / G95).

G94 (the start): F program units per minute. G95: F units per revolution
of the spindle, at the last programmed S (rpm): F S units per minute; the
gantry has no spindle, the product is the feed. G93 (inverse time): F on
every feed block is the inverse of its time in minutes, so the block's
moves (an arc split where its end is off its circle, a spline's arcs)
share the one feed that takes 60 / F s over their length (in XY: the
dropped Z is not counted).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

from gantry_twin.gcode.geometry import Move


class FeedModes:
    """The feed half of :class:`~gantry_twin.gcode.machine.Machine`."""

    feed_mode: str  # "G93", "G94" or "G95"
    f_word: float  # the last F, program units
    spindle_rpm: float  # the last S
    feed_m_s: float | None  # G94's F, m/s (None: no F yet)
    motion: int | str | None
    position: tuple[float, float]
    start: tuple[float, float] | None
    scale_m: float
    exact_stop: bool
    tolerance_m: float
    error: Callable[[str, str], Exception]

    def feed_common(self, words: dict[str, float], number: int) -> dict:
        """The fields a move of this block shares: the feed (m/s; inf for a rapid; G93: placed by
        :meth:`timed`), the line and the path mode; the program's start placed before its first move."""
        if self.start is None:
            self.start = self.position
        rapid = self.motion == 0
        if rapid:
            feed = math.inf
        elif self.feed_mode == "G94" and self.feed_m_s:
            feed = self.feed_m_s  # the common case first
        else:
            feed = self.feed_other(words)
        return dict(feed_m_s=feed, rapid=rapid, line=number, exact_stop=self.exact_stop, tolerance_m=self.tolerance_m)

    def feed_other(self, words: dict[str, float]) -> float:
        """A feed block's feed, m/s, but G94's with F > 0: G95's, G93's placeholder, or the error of none."""
        code = f"G{self.motion}" if isinstance(self.motion, int) else str(self.motion)
        if self.feed_mode == "G93":
            if words.get("F", 0.0) <= 0.0:
                raise self.error(code, "G93 (inverse time) needs F > 0 on every feed move (1 / minutes)")
            return math.inf  # placed by timed()
        if self.feed_mode == "G95":
            if self.f_word <= 0.0 or self.spindle_rpm <= 0.0:
                what = "F is 0" if self.f_word <= 0.0 else "the spindle speed S is 0"
                raise self.error(code, f"no feed: {what} (G95: F units per revolution times S rpm)")
            return self.f_word * self.spindle_rpm * self.scale_m / 60.0
        what = "F must be given before the first feed move" if self.feed_m_s is None else "F is 0"
        raise self.error(code, f"no feed: {what}")

    def timed(self, moves: list[Move], words: dict[str, float]) -> list[Move]:
        """G93: the block's moves at the one feed that takes 60 / F s over all of them (else as they are)."""
        if self.feed_mode != "G93" or not moves or moves[0].rapid:
            return moves
        feed = sum(m.length_m for m in moves) * words["F"] / 60.0
        return [dataclasses.replace(m, feed_m_s=feed) for m in moves]
