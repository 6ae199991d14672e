"""Every file a command writes, atomically: a hidden temporary beside it, fsync, then ``os.replace``.

A crash leaves either the old file, the new file, or a hidden
``.<name>.<pid>.*.part`` file (``pid``: the process that made it; :func:`remove_stale_temporaries` removes
those whose process is gone), never a half-written file under the final name; an
exception (Ctrl-C, and SIGTERM and SIGHUP under the command line) removes the
temporary file. Nothing is ever renamed over an existing path that is not a regular file (a device such as
/dev/null, a FIFO, a socket, a directory): :class:`NotRegularFileError` instead, and the path is left as it was.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

import pyarrow as pa
import pyarrow.parquet as pq

from gantry_twin.outputs.signals import signals_held


class NotRegularFileError(FileExistsError):
    """An output path exists and is not a regular file: it is never replaced."""

    def __init__(self, path: Path, kind: str) -> None:
        super().__init__(errno.EEXIST, f"exists and is {kind}, not a regular file; it is never replaced", str(path))


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    return "not a plain file"


def check_replaceable(path: Path) -> None:
    """Refuse (``NotRegularFileError``) when ``path`` exists, behind any symlink, and is not a regular file."""
    try:
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return
    except OSError:
        mode = os.lstat(path).st_mode  # e.g. a symlink loop: the link itself is what would be replaced
    if not stat.S_ISREG(mode):
        raise NotRegularFileError(Path(path), _kind(mode))


def _prefix(path: Path) -> str:
    return f".{path.name}.{os.getpid()}."


#: A temporary of this module: ``.<name>.<pid>.<random>.part`` (mkstemp's random part has no dot).
_TEMPORARY = re.compile(r"\..+\.(\d+)\.[^.]+\.part")


def _alive(pid: int) -> bool:
    """Whether a process ``pid`` exists (one of another user's counts: it is not ours to judge)."""
    if pid <= 0:
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


def remove_stale_temporaries(directory: Path) -> list[str]:
    """Remove the temporaries (files or directories) in ``directory`` whose process is gone (e.g. SIGKILLed);
    returns their names. Those of live processes, this one included, and every other file are left alone."""
    removed = []
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return removed
    for entry in entries:
        found = _TEMPORARY.fullmatch(entry.name)
        if found is None or _alive(int(found.group(1))):
            continue
        if entry.is_dir(follow_symlinks=False):
            remove_tree(Path(entry.path))
        else:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(entry.path)
        removed.append(entry.name)
    return removed


def temporary_file(path: Path) -> tuple[IO[bytes], Path]:
    """A new hidden ``.<name>.<pid>.*.part`` file beside ``path`` (with the usual permissions), open for writing.

    Create and name it inside ``with signals_held():`` within the ``try``
    whose ``except`` discards it, so that an interrupt comes after the name is known. ``NotRegularFileError``
    when ``path`` exists and is not a regular file (checked again by :func:`commit`).
    """
    check_replaceable(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=_prefix(path), suffix=".part")
    try:
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        return os.fdopen(fd, "wb"), Path(tmp)
    except BaseException:
        os.close(fd)
        os.unlink(tmp)
        raise


def commit(fh: IO[bytes], tmp: Path, path: Path) -> None:
    """Flush, fsync and close ``fh`` (the temporary file ``tmp``), rename it to ``path``, fsync the directory."""
    fh.flush()
    os.fsync(fh.fileno())
    fh.close()
    check_replaceable(path)
    os.replace(tmp, path)
    _fsync_dir(path.parent)


def temporary_path(path: Path) -> Path:
    """A new, empty, closed temporary beside ``path`` (:func:`temporary_file`) for a writer that opens it by name
    (rerun's recording); :func:`commit_file` renames it to ``path``, or unlink it."""
    with signals_held():
        fh, tmp = temporary_file(path)
        fh.close()
    return tmp


def commit_file(tmp: Path, path: Path) -> None:
    """:func:`commit` for a temporary written and closed by someone else: fsync, rename to ``path``, fsync the
    directory (``NotRegularFileError`` if ``path`` has become a FIFO, device, socket or directory)."""
    with open(tmp, "rb") as fh:
        os.fsync(fh.fileno())
    check_replaceable(path)
    os.replace(tmp, path)
    _fsync_dir(path.parent)


def discard(fh: IO[bytes] | None, tmp: Path | None) -> None:
    """Close and remove a temporary file (whatever state it is in)."""
    if fh is not None:
        with contextlib.suppress(OSError):
            fh.close()
    if tmp is not None:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)


def atomic_write(path: Path, write: Callable[[IO[bytes]], None]) -> None:
    """Write a file via temp file + fsync + os.replace; on error no file appears."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fh = tmp = None
    try:
        with signals_held():
            fh, tmp = temporary_file(path)
        write(fh)
        commit(fh, tmp, path)
    except BaseException:
        discard(fh, tmp)
        raise


def remove_tree(path: Path) -> None:
    """Remove a directory and what it holds, if it exists."""
    import shutil

    shutil.rmtree(path, ignore_errors=True)


def atomic_write_dir(path: Path, write: Callable[[Path], None]) -> None:
    """Fill a directory via a hidden ``.<name>.<pid>.*.part`` directory beside it renamed to ``path`` (an earlier
    ``path`` is removed first); on error no directory appears."""
    path = Path(path)
    tmp = None
    try:
        with signals_held():
            tmp = Path(tempfile.mkdtemp(dir=path.parent, prefix=_prefix(path), suffix=".part"))
        os.chmod(tmp, 0o777 & ~_umask())
        write(tmp)
        remove_tree(path)
        os.replace(tmp, path)
        _fsync_dir(path.parent)
    except BaseException:
        if tmp is not None:
            remove_tree(tmp)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write(path, lambda fh: fh.write(text.encode("utf-8")))


def _fsync_dir(directory: Path) -> None:
    """Make the rename durable (POSIX; a no-op where directories cannot be opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


#: Parquet writer options: float columns rarely repeat a value, so dictionary pages would only add to the file.
PARQUET_OPTIONS: dict[str, Any] = {"use_dictionary": False}


def write_parquet(path: Path, table: pa.Table) -> None:
    atomic_write(path, lambda fh: pq.write_table(table, fh, **PARQUET_OPTIONS))
