"""Where runs go by default: one new directory per run, and ``latest`` (docs/cli.md, "Run directories").

``gantry-twin run`` and ``monitor`` without ``--out`` write into
``runs/<name>/<UTC time>-<id>/``, e.g. ``runs/no_load_circle/20261201T021530Z-3f9a1c/``:
the time the run started (``%Y%m%dT%H%M%SZ``, so names sort by time) and
six random hex digits that tell apart two runs started in the same second.
Nothing is overwritten. Once a run has finished with ``status: ok`` and its
``summary.json`` is written, ``runs/<name>/latest`` names it: a relative
symbolic link to the directory (``latest -> 20261201T021530Z-3f9a1c``),
replaced atomically (a new link renamed over the old one); where symbolic
links cannot be made, a text file ``latest`` holding the directory's name
and a newline. A run that is interrupted or fails leaves ``latest`` as it was.
"""

from __future__ import annotations

import os
import secrets
import time
from pathlib import Path

from gantry_twin.inputs import InputFileError, read_input_file
from gantry_twin.outputs.files import atomic_write_text
from gantry_twin.settings import quote

#: The name of the pointer to a name's last complete run.
LATEST = "latest"
#: Largest ``latest`` text file read: a run directory's name is some 30 characters.
LATEST_MAX_BYTES = 4096
#: The time part of a run directory's name (UTC).
STAMP_FORMAT = "%Y%m%dT%H%M%SZ"


def new_run_dir(base: Path, now_s: float | None = None) -> Path:
    """A directory name under ``base`` for a new run, not yet taken (the directory is not made)."""
    stamp = time.strftime(STAMP_FORMAT, time.gmtime(time.time() if now_s is None else now_s))
    while True:
        candidate = Path(base) / f"{stamp}-{secrets.token_hex(3)}"
        if not candidate.exists():
            return candidate


def point_latest(run_dir: Path) -> Path:
    """Make ``<run_dir's parent>/latest`` name ``run_dir`` (module docstring); the pointer's path.

    OSError if neither a link nor a file can be written there (e.g. a directory named ``latest`` is in the way).
    """
    run_dir = Path(run_dir)
    latest = run_dir.parent / LATEST
    tmp = run_dir.parent / f".{LATEST}.{secrets.token_hex(4)}.part"
    try:
        os.symlink(run_dir.name, tmp, target_is_directory=True)
    except (OSError, NotImplementedError):  # no symbolic links here: a text file
        atomic_write_text(latest, run_dir.name + "\n")
        return latest
    try:
        os.replace(tmp, latest)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return latest


def resolve_run(path: Path) -> Path:
    """The run directory a path names: the directory itself, ``latest`` (link or text file), or a directory
    holding ``latest`` (``runs/<name>``). The result may lack summary.json: the caller checks. InputFileError
    when a ``latest`` text file is not a regular file of at most LATEST_MAX_BYTES naming a directory beside it."""
    path = Path(path)
    if path.is_file() and path.name == LATEST:  # the text-file form: one directory name and a newline
        try:
            name = read_input_file(path, "a run directory's name and a newline", LATEST_MAX_BYTES).strip()
        except InputFileError as exc:
            raise InputFileError(f"{path}: {exc}") from None
        if not name or "/" in name or "\0" in name or name in (".", ".."):
            raise InputFileError(f"{path}: holds {quote(name)}, not the name of a run directory beside it")
        return path.parent / name
    if path.is_dir() and not (path / "summary.json").exists() and (path / LATEST).exists():
        return resolve_run(path / LATEST)
    return path
