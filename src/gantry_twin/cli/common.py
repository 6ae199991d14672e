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

from gantry_twin.outputs.files import NotRegularFileError, check_replaceable
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


def _probe_dir(out: Path, option: str) -> list[Path]:
    """Make ``out`` and a temporary file in it; the directories made (deepest first). BadInput, one line, if it
    cannot be written (whatever was made removed again)."""
    checked_out(out)
    made = [d for d in (out, *out.parents) if not d.exists()]  # deepest first
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as exc:
        _remove_empty(made)
        raise BadInput(f"{option} {out}: cannot write there ({exc.strerror or exc})") from None
    return made


def _remove_empty(directories: list[Path]) -> None:
    for directory in directories:
        with contextlib.suppress(OSError):
            directory.rmdir()  # only if empty


def check_writable(out: Path, option: str = "--out") -> Path:
    """The one check of an output directory before any work (BadInput, one line, exit 2, if a file is in the way
    or the directory cannot be made or written); it leaves nothing behind. :func:`writable_out` keeps it made."""
    _remove_empty(_probe_dir(out, option))
    return out


@contextlib.contextmanager
def writable_out(out: Path, option: str = "--out") -> Iterator[Path]:
    """:func:`check_writable`, the directory kept made for the command's files: a read-only folder is found in
    milliseconds, not after minutes of runs. A directory made here is removed again if the command then fails with
    it still empty (nothing left behind)."""
    made = _probe_dir(out, option)
    try:
        yield out
    except BaseException:
        _remove_empty(made)
        raise


def writable_file(path: Path, option: str = "--out", what: str = "") -> Path:
    """A file a command will write (atomically, beside itself): BadInput, one line, unless its folder exists and a
    file can be made in it, and the path is not something that is never replaced (a directory, FIFO, socket or
    device: :func:`gantry_twin.outputs.files.check_replaceable`). ``what``: a hint after the reason."""
    hint = f" ({what})" if what else ""
    try:
        check_replaceable(path)
    except NotRegularFileError as exc:
        raise BadInput(f"{option} {path}: {exc.strerror}{hint}") from None
    try:
        with tempfile.TemporaryFile(dir=path.parent):
            pass
    except OSError as exc:
        raise BadInput(f"{option} {path}: cannot write there ({exc.strerror or exc})") from None
    return path


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
    """--out, else a new run directory under runs/<name>/ (gantry_twin.outputs.rundirs); either checked writable
    (:func:`check_writable`), nothing made."""
    if out is not None:
        return check_writable(out)
    base = checked_out(RUNS_DIR / (scenario.outputs.dir or str(scenario.name)))  # labels (settings.Label): under runs/
    return check_writable(new_run_dir(base), "output directory")


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
