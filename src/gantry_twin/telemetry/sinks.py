"""Where a recording goes and how fast the run goes: the native viewer, the local web viewer, a running
viewer's URL, and pacing to the wall clock.

Every check here fails with :class:`TelemetryError`, one line meant for the user, before anything is opened.
"""

from __future__ import annotations

import atexit
import math
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.parse
from collections.abc import Sequence
from pathlib import Path

import rerun as rr

from gantry_twin.loop.trace import RunInfo, Trace
from gantry_twin.settings import quote

#: Every server and viewer this module starts listens on the loopback interface only.
LOCALHOST = "127.0.0.1"


class TelemetryError(RuntimeError):
    """Telemetry cannot start; the message is one line, meant for the user."""


# ---------------------------------------------------------------------------------------------
# Pacing


class RealtimePacer:
    """Sleeps after each chunk so that simulated time / wall time = ``factor`` (1 = real time)."""

    def __init__(self, factor: float = 1.0) -> None:
        if not (math.isfinite(factor) and factor > 0):
            raise ValueError(f"realtime factor must be a number > 0, got {quote(factor)}")
        self.factor = float(factor)

    def on_start(self, run: RunInfo, trace: Trace) -> None:
        self._t0 = time.perf_counter()
        self._ts = trace.sample_period_s or run.plant.timestep_s

    def on_chunk(self, trace: Trace, start: int, stop: int) -> None:
        due = self._t0 + stop * self._ts / self.factor
        delay = due - time.perf_counter()
        if delay > 0:
            time.sleep(delay)

    def on_end(self, trace: Trace) -> None:
        pass


# ---------------------------------------------------------------------------------------------
# Sinks: display check, URL check, the local web viewer


def has_display() -> bool:
    """True where a native viewer window can open (Linux/BSD: $DISPLAY or $WAYLAND_DISPLAY set)."""
    if not sys.platform.startswith(("linux", "freebsd", "openbsd", "netbsd")):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def require_display() -> None:
    """TelemetryError (pointing at --serve-web) where a native viewer window cannot open."""
    if not has_display():
        raise TelemetryError(
            "--viewer: no display here ($DISPLAY and $WAYLAND_DISPLAY are unset); "
            "use --serve-web and open the printed URL in a browser, or --save FILE.rrd"
        )


def local_grpc_url(port: int) -> str:
    """The URL a recording streams to for a viewer or server listening on ``port`` of this machine."""
    return f"rerun+http://{LOCALHOST}:{port}/proxy"


def spawn_native_viewer(recording: rr.RecordingStream) -> str:
    """Start the native viewer on a free local port (blocks until it listens); its gRPC URL."""
    port = free_port()
    rr.spawn(port=port, connect=False, hide_welcome_screen=True, executable_path=rerun_binary(), recording=recording)
    return local_grpc_url(port)


def check_grpc_url(url: str) -> str:
    """``url`` if it names a rerun gRPC endpoint (``rerun+http://HOST:PORT/proxy``), else TelemetryError."""
    parsed = urllib.parse.urlparse(url)
    if parsed.scheme not in ("rerun", "rerun+http", "rerun+https") or not parsed.netloc:
        raise TelemetryError(f"--connect: URL must look like rerun+http://HOST:PORT/proxy, got {quote(url)}")
    return url


def free_port() -> int:
    """A TCP port nobody listens on at the moment, on the loopback interface."""
    with socket.socket() as s:
        s.bind((LOCALHOST, 0))
        return int(s.getsockname()[1])


def wait_for_port(port: int, process: subprocess.Popen, timeout_s: float) -> bool:
    """True once something listens on local ``port``; False if ``process`` exits first or time runs out."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if process.poll() is not None:
            return False
        with socket.socket() as s:
            s.settimeout(0.2)
            if s.connect_ex((LOCALHOST, port)) == 0:
                return True
        time.sleep(0.05)
    return False


def rerun_binary() -> str:
    """The rerun viewer/server binary shipped with rerun-sdk (not the Python wrapper, which would
    leave the binary running when terminated)."""
    if "RERUN_CLI_PATH" in os.environ:
        given = os.environ["RERUN_CLI_PATH"]
        if not (os.path.isfile(given) and os.access(given, os.X_OK)):
            raise TelemetryError(f"RERUN_CLI_PATH {given}: not an executable file (the rerun viewer binary)")
        return given
    try:
        import rerun_cli
    except ImportError:
        raise TelemetryError("the rerun viewer binary is not installed (pip install rerun-sdk)") from None

    folder = Path(rerun_cli.__file__).parent
    candidates = [folder / "Rerun.app" / "Contents" / "MacOS" / "Rerun", folder / "rerun", folder / "rerun.exe"]
    for candidate in candidates:
        if candidate.is_file():
            return str(candidate)
    raise TelemetryError(f"the rerun binary is missing from {folder} (reinstall rerun-sdk)")


def _end_with_parent() -> None:
    """In a child process before it runs (Linux): SIGTERM when the process that started it ends, however it
    ends (even SIGKILL)."""
    import ctypes

    pr_set_pdeathsig = 1
    ctypes.CDLL(None).prctl(pr_set_pdeathsig, int(signal.SIGTERM))


class WebViewerServer:
    """rerun's web viewer and gRPC server in a child process, bound to 127.0.0.1 only.

    ``recordings``: .rrd files the server shows from the start (else it shows what is streamed to ``grpc_url``).
    The process is stopped by :meth:`stop` (at exit at the latest); on Linux it also ends when this process
    ends without stopping it.
    """

    def __init__(
        self,
        grpc_port: int | None = None,
        web_port: int | None = None,
        timeout_s: float = 20.0,
        recordings: Sequence[str | os.PathLike[str]] = (),
    ) -> None:
        self.grpc_port = grpc_port or free_port()
        self.web_port = web_port or free_port()
        self.grpc_url = local_grpc_url(self.grpc_port)
        query = urllib.parse.urlencode({"url": self.grpc_url})
        self.url = f"http://{LOCALHOST}:{self.web_port}/?{query}"
        command = [rerun_binary(), "--serve-web", "--bind", LOCALHOST]
        command += ["--port", str(self.grpc_port), "--web-viewer-port", str(self.web_port), *map(str, recordings)]
        self._log = tempfile.TemporaryFile(mode="w+")
        linux = sys.platform.startswith("linux")
        self.process = subprocess.Popen(
            command,
            stdin=subprocess.DEVNULL,
            stdout=self._log,
            stderr=self._log,
            preexec_fn=_end_with_parent if linux else None,
        )
        atexit.register(self.stop)
        try:
            listening = wait_for_port(self.grpc_port, self.process, timeout_s) and wait_for_port(
                self.web_port, self.process, timeout_s
            )
        except BaseException:  # interrupted while it starts
            self.stop()
            raise
        if not listening:
            self.stop()
            self._log.seek(0)
            last = next((line.strip() for line in reversed(self._log.read().splitlines()) if line.strip()), "")
            raise TelemetryError(f"--serve-web: the rerun web viewer did not start ({last or 'no output'})")

    def stop(self) -> None:
        """Stop the server process (idempotent)."""
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        atexit.unregister(self.stop)
