"""The one door every input file comes through: regular files only (stat before open), a size cap, UTF-8.

A directory, device, FIFO or socket (also behind a symlink, e.g. to
/dev/zero) is refused without being opened; at most the cap plus one byte is
ever read, so a huge or endless input costs bounded time and memory. The
messages are one line saying why (docs/hostile-input.md).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

#: Largest file read as YAML or JSON (a scenario file, ``monitor.baseline_summary``), bytes. A scenario
#: is a few hundred bytes and a run's summary.json a few KiB; the cap bounds the time and memory of a parse.
INPUT_MAX_BYTES = 256 * 1024


class InputFileError(ValueError):
    """A file that is not read: one line saying why (no such file, a device, too large, not UTF-8)."""


def check_input_file(path: str | Path, what: str, max_bytes: int | None = None) -> os.stat_result:
    """The ``stat`` of a regular file (behind any symlink) of at most ``max_bytes``; else :class:`InputFileError`.

    Nothing is opened: a directory, device, FIFO or socket is refused before a read could block on it or run
    without end. For readers that open the file themselves (a parquet trace, a MuJoCo model, a log).
    """
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise InputFileError(f"no such file; give {what}") from None
    except OSError as exc:
        raise InputFileError(f"cannot read ({exc.strerror}); give {what}") from None
    if stat.S_ISDIR(info.st_mode):
        raise InputFileError(f"is a directory; give {what}")
    if not stat.S_ISREG(info.st_mode):
        raise InputFileError(f"is not a regular file (a device, FIFO or socket); give {what}")
    if max_bytes is not None and info.st_size > max_bytes:
        raise InputFileError(_too_large(max_bytes, what))
    return info


def _too_large(max_bytes: int, what: str) -> str:
    size = f"{max_bytes // (1 << 20)} MiB" if max_bytes >= 1 << 20 else f"{max_bytes // 1024} KiB"
    return f"is larger than {size}, the limit for {what}"


def read_input_file(path: str | Path, what: str, max_bytes: int = INPUT_MAX_BYTES) -> str:
    """The UTF-8 text of a regular file of at most ``max_bytes`` (:data:`INPUT_MAX_BYTES`); else
    :class:`InputFileError`.

    Checked before anything is read (:func:`check_input_file`): a directory, device, FIFO or socket (also
    behind a symlink, e.g. to /dev/zero) is refused without being opened, and
    at most ``max_bytes`` + 1 bytes are ever read. ``what`` names what the
    file should be ("a scenario YAML file").
    """
    check_input_file(path, what, max_bytes)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
        with os.fdopen(fd, "rb") as fh:
            if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):  # replaced since the stat above
                raise InputFileError(f"is not a regular file; give {what}")
            data = fh.read(max_bytes + 1)
    except OSError as exc:
        raise InputFileError(f"cannot read ({exc.strerror}); give {what}") from None
    if len(data) > max_bytes:
        raise InputFileError(_too_large(max_bytes, what))
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise InputFileError(f"not UTF-8 text; give {what}") from None
