"""What every subcommand shares: the program's name, the exit codes (docs/cli.md), bad input, a failed command."""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
import tempfile
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path

from gantry_twin.outputs.rundirs import new_run_dir
from gantry_twin.scenario import Scenario, resolve_scenario, shipped
from gantry_twin.settings import quote

PROG = "gantry-twin"

EXIT_OK = 0
EXIT_RUN_FAILED = 1  # also: a sweep whose every point failed
EXIT_BAD_INPUT = 2
EXIT_ALARM = 3
EXIT_END_STOP = 4
EXIT_NOT_JUDGED = 5  # monitor: no parameter was ever judged (all in the baseline window or not excited)
EXIT_INTERRUPTED = 128  # + the signal's number, as shells report it: 130 SIGINT, 143 SIGTERM, 129 SIGHUP


#: The scenario a command runs when none is named.
DEFAULT_SCENARIO = "no_load_circle"
#: Where a run's directory goes when --out names none.
RUNS_DIR = Path("runs")


class BadInput(Exception):
    """Bad command-line input that is not a scenario field (exit code 2)."""


def checked_out(out: Path) -> Path:
    """An output directory that exists or can be made (BadInput if a file is in the way)."""
    if out.exists() and not out.is_dir():
        raise BadInput(f"--out {out}: exists and is not a directory")
    return out


@contextlib.contextmanager
def writable_out(out: Path) -> Iterator[Path]:
    """:func:`checked_out`, made, and a file can be made in it (BadInput otherwise): for a command that would start
    workers, a cluster or minutes of work before its first file (a read-only folder found before, not after). A
    directory made here is removed again if the command then fails with it still empty (nothing left behind)."""
    checked_out(out)
    made = [d for d in (out, *out.parents) if not d.exists()]  # deepest first
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as exc:
        raise BadInput(f"--out {out}: cannot write there ({exc.strerror or exc})") from None
    try:
        yield out
    except BaseException:
        for directory in made:
            with contextlib.suppress(OSError):
                directory.rmdir()  # only if empty
        raise


def failed(what: str, exc: Exception) -> int:
    """One line on stderr for a run or report that failed (not the user's input); GANTRY_TWIN_DEBUG re-raises."""
    if os.environ.get("GANTRY_TWIN_DEBUG"):
        raise exc
    message = str(exc).splitlines()[0] if str(exc) else ""
    print(f"{PROG}: {what} failed: {type(exc).__name__}: {message}", file=sys.stderr)
    return EXIT_RUN_FAILED


def scenario_path(arg: str | None) -> Path:
    """A file path, or the name of a shipped scenario (``no_load_circle``) when no such file exists."""
    if arg is None:
        return shipped(DEFAULT_SCENARIO)
    try:
        return resolve_scenario(arg)
    except FileNotFoundError as exc:
        raise BadInput(str(exc)) from None


def out_dir(out: Path | None, scenario: Scenario) -> Path:
    """--out, else a new run directory under runs/<name>/ (gantry_twin.outputs.rundirs)."""
    if out is not None:
        return checked_out(out)
    base = checked_out(RUNS_DIR / (scenario.outputs.dir or str(scenario.name)))  # labels (settings.Label): under runs/
    return new_run_dir(base)


def number_type(
    what: str,
    must: str,
    lo: float,
    hi: float = math.inf,
    lo_open: bool = False,
    integer: bool = False,
    words: Mapping[str, float] | None = None,
) -> Callable[[str], float]:
    """An argparse ``type``: a number in [lo, hi] ((lo, hi] with ``lo_open``; an integer with ``integer``), or one
    of ``words`` (its value); else ``WHAT must be MUST, got 'TEXT'`` (one line, exit 2)."""

    def parse(text: str) -> float:
        if words and text.strip().lower() in words:
            return words[text.strip().lower()]
        try:
            value = int(text) if integer else float(text)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and (value > lo if lo_open else value >= lo) and value <= hi):
            raise argparse.ArgumentTypeError(f"{what} must be {must}, got {quote(text)}")
        return value

    return parse
