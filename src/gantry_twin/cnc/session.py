"""LinuxCNC's processes: started, watched and stopped here and nowhere else.

LinuxCNC runs as separate programs (its ``linuxcnc`` launcher, task, motion
in ``rtapi_app``, HAL's tools), never loaded into the twin's process; the
twin writes their files, reads what they write and signals them
(docs/linuxcnc.md, the licence note). A :class:`Session` is one LinuxCNC
run in a private directory; LinuxCNC keeps machine-wide state (System V
shared memory with fixed keys, ``/tmp/linuxcnc.lock``), so one runs at a
time on a machine: :func:`machine_lock` serialises the twin's sessions and
a LinuxCNC already running (not the twin's) is refused, not disturbed.

Stopping, on every path (the end, an error, Ctrl-C, a killed launcher):
SIGTERM to the launcher, which shuts LinuxCNC down in order; past
``GRACE_S``, SIGKILL to the session's processes (the launcher's process
group, and the servers that start sessions of their own, found by the
session's marker in their environment); then what a killed launcher leaves
is removed: the shared-memory segments that appeared with the session and
that no process holds, the launcher's lock and log files, the directory.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

from gantry_twin.outputs.signals import signals_held

#: The launcher, LinuxCNC's HAL tool and standalone interpreter, and the Python that has LinuxCNC's modules.
LAUNCHER, HALCMD, RS274, SYSTEM_PYTHON = "linuxcnc", "halcmd", "rs274", "/usr/bin/python3"
#: The abstract socket name the twin's sessions take turns on (LinuxCNC's state is machine-wide).
LOCK_NAME = "\0gantry-twin-linuxcnc"
#: LinuxCNC's own lock and log files (its launcher's fixed names).
LINUXCNC_LOCK = Path("/tmp/linuxcnc.lock")
LINUXCNC_LOGS = ("linuxcnc.debug.*", "linuxcnc.print.*")
#: The System V shared-memory key of HAL: present while any LinuxCNC or HAL session runs.
HAL_SHM_KEY = 0x48414C32
#: Seconds the launcher gets to shut LinuxCNC down after SIGTERM before the processes are killed.
GRACE_S = 10.0
#: The environment variable that marks a session's processes.
MARKER = "GANTRY_TWIN_CNC_SESSION"
#: LinuxCNC's processes whose end, while the launcher runs, ends the session; seconds between two looks.
ESSENTIAL = ("rtapi_app", "milltask", "linuxcncsvr", "io")
WATCH_S = 0.25
#: A non-root user's id for LinuxCNC's realtime part when the twin runs as root (it refuses root).
NOBODY_UID = 65534


class LinuxCncError(RuntimeError):
    """LinuxCNC could not run or stopped with an error: one line saying what and why."""


def missing() -> str | None:
    """Why LinuxCNC cannot run here (None when it can): the programs and the system Python's module."""
    for program in (LAUNCHER, HALCMD, RS274, "halsampler"):
        if shutil.which(program) is None:
            return f"LinuxCNC's {program!r} is not on PATH (Debian: apt-get install linuxcnc-uspace)"
    if not Path(SYSTEM_PYTHON).exists():
        return f"{SYSTEM_PYTHON} (Debian's Python 3, which has LinuxCNC's module) is missing"
    probe = subprocess.run([SYSTEM_PYTHON, "-c", "import linuxcnc, hal"], capture_output=True, timeout=30)
    if probe.returncode:
        return f"{SYSTEM_PYTHON} cannot import LinuxCNC's 'linuxcnc' module (Debian: apt-get install linuxcnc-uspace)"
    return None


@contextlib.contextmanager
def turn(name: str, timeout_s: float, what: str) -> Iterator[None]:
    """Hold a machine-wide turn: an abstract Unix socket's ``name`` that one process at a time can bind, released
    when it ends however it ends, no file; :class:`LinuxCncError` naming ``what`` after ``timeout_s`` of waiting."""
    lock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                lock.bind(name)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise LinuxCncError(f"{what} held the machine's turn for {timeout_s:g} s") from None
                time.sleep(0.1)
        yield
    finally:
        lock.close()


def machine_lock(timeout_s: float = 600.0) -> contextlib.AbstractContextManager[None]:
    """Hold the machine's LinuxCNC turn (:data:`LOCK_NAME`), waiting at most ``timeout_s`` for it."""
    return turn(LOCK_NAME, timeout_s, "another gantry-twin LinuxCNC session")


def shm_segments() -> dict[int, tuple[int, int]]:
    """The machine's System V shared-memory segments: key -> (shmid, processes attached)."""
    out = subprocess.run(["ipcs", "-m"], capture_output=True, text=True, timeout=10).stdout
    found = {}
    for line in out.splitlines():
        words = line.split()
        if len(words) >= 6 and words[0].startswith("0x"):
            found[int(words[0], 16)] = (int(words[1]), int(words[5]))
    return found


def linuxcnc_running() -> bool:
    """A LinuxCNC (or HAL session) runs on this machine: HAL's segment exists with a process attached."""
    segment = shm_segments().get(HAL_SHM_KEY)
    return segment is not None and segment[1] > 0


class Session:
    """One LinuxCNC run of ``ini`` (a file in ``directory``, which the session owns and removes).

    Use as a context manager inside :func:`machine_lock`: :meth:`start`, then
    :meth:`wait`; leaving the block stops LinuxCNC and removes everything it
    left, on every path. ``display``: the file name of the ``[DISPLAY]``
    program; when it ends, LinuxCNC shuts down.
    """

    def __init__(self, directory: Path, ini: Path, display: str) -> None:
        self.directory, self.ini = Path(directory), Path(ini)
        self.display = display[:15]  # the display program's command name, as /proc gives it
        self.process: subprocess.Popen | None = None
        self._before: dict[int, tuple[int, int]] = {}
        self._logs_before: set[Path] = set()
        self._marker = f"{os.getpid()}-{time.monotonic_ns()}"

    @staticmethod
    def make_directory() -> Path:
        """A private directory for a session (LinuxCNC's realtime part, run as another user, writes its socket
        there: it is world-writable and sticky, inside a directory only the twin's user can list)."""
        parent = Path(tempfile.mkdtemp(prefix="gantry-twin-linuxcnc-"))
        parent.chmod(0o711)
        home = parent / "session"
        home.mkdir()
        home.chmod(0o1777)
        return home

    def start(self) -> None:
        if linuxcnc_running():
            raise LinuxCncError("another LinuxCNC runs on this machine (HAL's shared memory is in use); stop it first")
        self._before = shm_segments()
        self._logs_before = _launcher_logs()
        env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "PYTHONPATH")}
        env.update({"HOME": str(self.directory), "TMPDIR": str(self.directory), MARKER: self._marker})
        venv = env.pop("VIRTUAL_ENV", None)
        if venv:  # LinuxCNC's own Python programs need Debian's python3 first on PATH, not a virtual environment's
            env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep) if not p.startswith(venv))
        if os.geteuid() == 0:
            env["RTAPI_UID"] = str(NOBODY_UID)
        with open(self.directory / "linuxcnc.out", "wb") as out:
            self.process = subprocess.Popen(
                [LAUNCHER, str(self.ini)], cwd=self.directory, env=env, stdin=subprocess.DEVNULL, stdout=out,
                stderr=subprocess.STDOUT, start_new_session=True,
            )  # fmt: skip

    def wait(self, timeout_s: float) -> int:
        """The launcher's exit status; :class:`LinuxCncError` if it runs longer than ``timeout_s`` or a part of
        LinuxCNC that it started (:data:`ESSENTIAL`) ends while the display program runs (a killed ``rtapi_app``
        leaves the display waiting for a motion that never comes; after the display, LinuxCNC shuts down)."""
        assert self.process is not None
        deadline = time.monotonic() + timeout_s
        seen: dict[str, int] = {}
        while True:
            try:
                return self.process.wait(WATCH_S)
            except subprocess.TimeoutExpired:
                pass
            if time.monotonic() > deadline:
                raise LinuxCncError(f"LinuxCNC did not end within {timeout_s:g} s")
            alive = {name: pid for pid, name in _marked_processes(self._marker, names=True)}
            if self.display in seen and self.display not in alive:
                continue  # the display ended: LinuxCNC is shutting down
            for name in ESSENTIAL:
                if name in seen and name not in alive and self.display in alive:
                    raise LinuxCncError(f"LinuxCNC's {name} (pid {seen[name]}) ended while the program ran")
            seen.update({name: pid for name, pid in alive.items() if name in (*ESSENTIAL, self.display)})

    def output(self) -> str:
        """What the launcher printed and logged (its own output and, after an error, the logs it copies to the
        session's home), the last 4 KiB of each."""
        parts = []
        for name in ("linuxcnc.out", "linuxcnc_print.txt", "linuxcnc_debug.txt"):
            try:
                parts.append((self.directory / name).read_bytes()[-4096:].decode("utf-8", "replace"))
            except OSError:
                continue
        return "\n".join(parts)

    def stop(self) -> None:
        """Stop LinuxCNC and remove what it left (idempotent; signals held off meanwhile are the caller's)."""
        process = self.process
        if process is not None and process.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                process.send_signal(signal.SIGTERM)  # the launcher's own orderly shutdown
            try:
                process.wait(GRACE_S)
            except subprocess.TimeoutExpired:
                pass
        self._kill_leftovers(process)
        self._remove_leftovers()

    def _kill_leftovers(self, process: subprocess.Popen | None) -> None:
        """SIGKILL every process still marked as this session's (and the launcher's group), and reap them. After a
        launcher that ended well, what LinuxCNC started gets GRACE_S to end on its own first (the live twin writes
        its summary once LinuxCNC is gone)."""
        if process is not None and process.returncode == 0:
            deadline = time.monotonic() + GRACE_S
            while _marked_processes(self._marker) and time.monotonic() < deadline:
                time.sleep(0.1)
        if process is not None:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(process.pid, signal.SIGKILL)
            with contextlib.suppress(subprocess.TimeoutExpired):
                process.wait(5)
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            alive = _marked_processes(self._marker)
            if not alive:
                return
            for pid in alive:
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.kill(pid, signal.SIGKILL)
            time.sleep(0.05)

    def _remove_leftovers(self) -> None:
        """The shared memory that came with the session and that nobody holds, LinuxCNC's lock and logs."""
        if self._before is not None and self.process is not None:
            for key, (shmid, attached) in shm_segments().items():
                if attached == 0 and (key not in self._before or self._before[key][0] != shmid):
                    subprocess.run(["ipcrm", "-m", str(shmid)], capture_output=True, timeout=10)
            for path in _launcher_logs() - self._logs_before:
                path.unlink(missing_ok=True)
            LINUXCNC_LOCK.unlink(missing_ok=True)
        shutil.rmtree(self.directory.parent, ignore_errors=True)

    def __enter__(self) -> Session:
        return self

    def __exit__(self, *exc: object) -> None:
        # A second Ctrl-C while stopping must not leave LinuxCNC behind: the stop runs with signals held.
        with signals_held():
            self.stop()


def _launcher_logs() -> set[Path]:
    return {p for pattern in LINUXCNC_LOGS for p in Path("/tmp").glob(pattern)}


def _marked_processes(marker: str, names: bool = False) -> list:
    """The processes whose environment carries ``MARKER=marker`` (zombies left out): their pids, or with
    ``names`` (pid, command name) pairs."""
    needle = f"{MARKER}={marker}".encode()
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            stat = (entry / "stat").read_text()
            command, rest = stat[stat.index("(") + 1 : stat.rindex(")")], stat[stat.rindex(")") + 2 :]
            if rest.startswith("Z"):
                continue
            if needle in (entry / "environ").read_bytes().split(b"\0"):
                found.append((int(entry.name), command) if names else int(entry.name))
        except (OSError, ValueError):
            continue
    return found
