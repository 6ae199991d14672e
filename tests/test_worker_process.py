"""A forked worker process (gantry_twin.loop.process): a function's value or exception comes back; a crash, an
exit, a hang past the limit or a worker past its memory limit is a WorkerEnded naming it; nothing is left behind,
and a command killed by SIGKILL has its worker's directory removed by the next one."""

from __future__ import annotations

import mmap
import os
import signal
import tempfile
from pathlib import Path

import pytest

from gantry_twin.loop import process
from gantry_twin.loop.process import SCRATCH_PREFIX, WorkerEnded, call_in_worker

pytestmark = pytest.mark.skipif(not hasattr(os, "fork") or not Path("/proc/self/statm").exists(), reason="Linux")


@pytest.fixture(autouse=True)
def private_tmp(tmp_path, monkeypatch) -> Path:
    root = tmp_path / "tmp"
    root.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(root))
    return root


def _resident_bytes() -> int:
    return int(Path("/proc/self/statm").read_text().split()[1]) * mmap.PAGESIZE


def _in_worker_tmp() -> str:
    """Where the worker's temporary files go, and a file there."""
    where = tempfile.mkdtemp()
    Path(where, "x").write_text("x")
    return where


def test_the_value_and_the_exception_come_back_and_its_files_go(private_tmp):
    where = call_in_worker(_in_worker_tmp, 30)
    assert Path(where).parent.name.startswith(f"{SCRATCH_PREFIX}{os.getpid()}-")
    assert call_in_worker(lambda: os.getpid(), 30) != os.getpid()
    with pytest.raises(ValueError, match="the worker's"):
        call_in_worker(lambda: (_ for _ in ()).throw(ValueError("the worker's")), 30)
    assert list(private_tmp.iterdir()) == []


@pytest.mark.parametrize(
    ("misbehave", "expected"),
    [
        (lambda: os.kill(os.getpid(), signal.SIGSEGV), "its process was killed by SIGSEGV (Segmentation fault)"),
        (lambda: os._exit(3), "its process exited with status 3"),
        (lambda: signal.pause(), "did not return within 0.5 s (its time limit); stopped"),
    ],
    ids=["segfault", "exit", "endless"],
)
def test_a_worker_that_ends_or_hangs_is_named(misbehave, expected, private_tmp):
    with pytest.raises(WorkerEnded) as caught:
        call_in_worker(misbehave, 0.5)
    assert str(caught.value) == expected
    assert list(private_tmp.iterdir()) == []


def test_a_worker_past_its_memory_limit_is_stopped(private_tmp):
    """The limit 100 MiB above what the worker starts with; it writes 400 MiB (at most 2x the limit is mapped)."""
    limit = _resident_bytes() + (100 << 20)

    def leak() -> None:
        held = bytearray(400 << 20)  # written: resident
        signal.pause()
        del held

    with pytest.raises(WorkerEnded, match=r"its process passed its memory limit of \d+ MiB \(\d+ MiB resident\)"):
        call_in_worker(leak, 60, limit)
    assert list(private_tmp.iterdir()) == []


def test_the_directory_of_a_killed_command_goes_with_the_next_worker(private_tmp, monkeypatch):
    """A command killed by SIGKILL leaves its worker's directory; the next command's first worker removes it, and
    leaves those of commands still running (this one's, and pid 1's)."""
    gone = os.fork()
    if gone == 0:
        os._exit(0)
    os.waitpid(gone, 0)
    stale = private_tmp / f"{SCRATCH_PREFIX}{gone}-abc"
    (stale / "gantry-twin-fmu-x").mkdir(parents=True)
    alive = [private_tmp / f"{SCRATCH_PREFIX}{pid}-abc" for pid in (os.getpid(), 1)]
    for path in alive:
        path.mkdir()
    monkeypatch.setattr(process, "_stale_removed", False)
    assert call_in_worker(lambda: 7, 30) == 7
    assert not stale.exists() and all(path.exists() for path in alive)
