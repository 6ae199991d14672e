"""The O-word structure of one file, checked before anything runs: which line closes which.

LinuxCNC matches an O-word's ``endwhile``, ``endif``, ``endsub``, ... to its
opening line by label (``o100`` or ``o<name>``); here the constructs must
also nest (a loop closed inside an ``if`` that opened outside it is an
error). :func:`structure` gives, for each O-word line index, the indices the
interpreter jumps to; a malformed structure raises :class:`StructureError`
with the line and column.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from gantry_twin.gcode.lexer import Line

_OPENS = {"sub": "endsub", "if": "endif", "while": "endwhile", "do": "while", "repeat": "endrepeat"}
_LOOPS = ("while", "do", "repeat")


class StructureError(ValueError):
    def __init__(self, line: int, column: int, word: str, what: str) -> None:
        self.line, self.column, self.word, self.what = line, column, word, what
        super().__init__(what)


@dataclass
class Structure:
    """Jumps by line index: ``end[i]`` the closing line of the construct opened at i (an ``if``'s next branch
    for if / elseif / else, the endif for the last); ``start[i]`` the opening line of a closing or of a
    break / continue; ``subs`` label -> (sub line, endsub line); ``closes_do`` the ``while`` lines that end
    a ``do``."""

    end: dict[int, int] = field(default_factory=dict)
    start: dict[int, int] = field(default_factory=dict)
    subs: dict[str, tuple[int, int]] = field(default_factory=dict)
    closes_do: set[int] = field(default_factory=set)
    endif: dict[int, int] = field(default_factory=dict)


def structure(lines: list[Line]) -> Structure:
    out = Structure()
    stack: list[tuple[str, str, int]] = []  # (label, keyword, index)
    for index, line in enumerate(lines):
        word = line.oword
        if word is None:
            continue
        label, keyword = word.label, word.keyword

        def fail(what: str, number=line.number, column=word.column, shown=f"{label} {keyword}") -> StructureError:
            return StructureError(number, column, shown, what)

        top = stack[-1] if stack else None
        if keyword == "while" and top is not None and top[:2] == (label, "do"):
            stack.pop()
            out.end[top[2]] = index
            out.start[index] = top[2]
            out.closes_do.add(index)
            continue
        if keyword in _OPENS:
            if keyword == "sub" and stack:
                raise fail(f"a subroutine cannot be defined inside {stack[-1][0]} {stack[-1][1]}")
            if any(entry[0] == label for entry in stack):
                raise fail("the label is already open (each construct needs its own O number)")
            stack.append((label, keyword, index))
            continue
        if keyword in ("elseif", "else", "endif"):
            if top is None or top[:2] != (label, "if") and not (top[0] == label and top[1] in ("elseif", "else")):
                raise fail(f"{keyword} without {label} if")
            if top[1] == "else" and keyword != "endif":
                raise fail(f"{keyword} after {label} else")
            stack.pop()
            out.end[top[2]] = index
            if keyword == "endif":
                head = top[2]
                for i in range(index, -1, -1):  # every branch of this if ends at this endif
                    if lines[i].oword and lines[i].oword.label == label and lines[i].oword.keyword in _BRANCH:
                        out.endif[i] = index
                        if lines[i].oword.keyword == "if" and i <= head:
                            break
            else:
                stack.append((label, keyword, index))
            continue
        closing = {v: k for k, v in _OPENS.items() if k != "do"}
        if keyword in closing:
            opener = closing[keyword]
            if top is None or top[:2] != (label, opener):
                if any(entry[:2] == (label, opener) for entry in stack):
                    raise fail(f"closes {label} {opener} while {top[0]} {top[1]} is still open")
                raise fail(f"{keyword} without {label} {opener}")
            stack.pop()
            out.end[top[2]] = index
            out.start[index] = top[2]
            if keyword == "endsub":
                out.subs[label] = (top[2], index)
            continue
        if keyword in ("break", "continue"):
            loop = next((e for e in reversed(stack) if e[0] == label and e[1] in _LOOPS), None)
            if loop is None:
                raise fail(f"{keyword} outside a loop labelled {label}")
            out.start[index] = loop[2]
            continue
        if keyword == "return":
            if not any(e[1] == "sub" for e in stack):  # LinuxCNC returns from the sub it is in, whatever the label
                raise fail("return outside a subroutine")
            continue
        # call: resolved when it runs
    if stack:
        label, keyword, index = stack[-1]
        word = lines[index].oword
        closer = _OPENS[keyword] if keyword in _OPENS else "endif"
        what = f"not closed (no {label} {closer})"
        raise StructureError(lines[index].number, word.column, f"{label} {keyword}", what)
    return out


_BRANCH = ("if", "elseif", "else")
