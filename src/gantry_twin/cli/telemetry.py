"""The telemetry options of a command line (--viewer, --save, --connect, --serve-web, --realtime) and the
observers they ask for; ``gantry-twin run`` and ``monitor`` use them (docs/telemetry.md).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

#: rerun's file writer logs its own lines on stderr when a write fails (disk full); --save reports that in one
#: line of its own (``TelemetryObservers.close``). Read by rerun when it is first imported; RUST_LOG if set wins.
os.environ.setdefault("RUST_LOG", "warn,re_log_encoding::rrd=off,re_sdk::recording_stream=off")

import rerun as rr  # noqa: E402 -- after its log filter

from gantry_twin.cli.common import number_type  # noqa: E402
from gantry_twin.loop.trace import Observer  # noqa: E402
from gantry_twin.outputs.files import (  # noqa: E402
    NotRegularFileError,
    check_replaceable,
    commit_file,
    remove_stale_temporaries,
    temporary_path,
)
from gantry_twin.settings import quote, shorten  # noqa: E402
from gantry_twin.telemetry.observer import RerunObserver  # noqa: E402
from gantry_twin.telemetry.sinks import (  # noqa: E402
    RealtimePacer,
    TelemetryError,
    WebViewerServer,
    check_grpc_url,
    require_display,
    spawn_native_viewer,
)

#: How long a recording's last data may take to reach its file, s.
SAVE_FLUSH_TIMEOUT_S = 60.0


_realtime_factor = number_type("FACTOR", "a number > 0 (1 = real time)", 0.0, lo_open=True)


def add_telemetry_arguments(parser: argparse.ArgumentParser) -> None:
    """Add --viewer, --save, --connect, --serve-web and --realtime (default: no telemetry, unpaced)."""
    group = parser.add_argument_group("telemetry (rerun)")
    group.add_argument("--viewer", action="store_true", help="spawn the rerun viewer and stream the run to it")
    group.add_argument("--save", metavar="FILE.rrd", type=Path, help="record the run; open later with `rerun FILE.rrd`")
    group.add_argument(
        "--connect", metavar="URL", help="stream to a running viewer, e.g. rerun+http://127.0.0.1:9876/proxy"
    )
    group.add_argument(
        "--serve-web", action="store_true", help="serve the web viewer on 127.0.0.1 (prints the URL; Ctrl-C stops)"
    )
    group.add_argument(
        "--realtime",
        metavar="FACTOR",
        nargs="?",
        const=1.0,
        default=None,
        type=_realtime_factor,
        help="pace the run to the wall clock: sim time / wall time = FACTOR (default 1)",
    )


class TelemetryObservers(list):
    """The observers for a run plus what they hold open; a list and a context manager.

    ``close()`` flushes every recording; with --serve-web it then keeps serving
    until Ctrl-C (``wait=True``) and stops the server.
    """

    def __init__(
        self,
        observers: Sequence[Observer],
        rerun_observer: RerunObserver | None,
        server: WebViewerServer | None,
        out: TextIO,
        save: Path | None = None,
        save_tmp: Path | None = None,
    ) -> None:
        super().__init__(observers)
        self.save = save
        #: --save's hidden temporary beside FILE.rrd, which rerun writes (renamed to FILE.rrd by close()).
        self.save_tmp = save_tmp
        #: One line saying why FILE.rrd was not written (a failed write, e.g. a full disk), else None.
        self.recording_failed: str | None = None
        self.rerun_observer = rerun_observer
        self.server = server
        self.out = out

    def close(self, wait: bool = True, complete: bool = True) -> None:
        """Flush the recording; ``--save``'s temporary renamed to FILE.rrd only when the run is ``complete`` and
        every byte reached the file (else removed: FILE.rrd as it was, :attr:`recording_failed` says why)."""
        try:
            if self.rerun_observer is not None:
                self._finish_recording(complete)
            if self.server is not None and wait:
                try:  # from before the message: Ctrl-C may come as soon as it is printed
                    print(f"Still serving the viewer at {self.server.url} ; press Ctrl-C to stop.", file=self.out)
                    self.out.flush()
                    while self.server.process.poll() is None:
                        time.sleep(0.2)
                except KeyboardInterrupt:
                    pass
        finally:
            if self.server is not None:
                self.server.stop()

    def _finish_recording(self, complete: bool) -> None:
        tmp, self.save_tmp = self.save_tmp, None
        committed = False
        try:
            try:
                if tmp is not None and complete:
                    self.rerun_observer.recording.flush(timeout_sec=SAVE_FLUSH_TIMEOUT_S)  # raises if a write failed
            except Exception as error:  # noqa: BLE001 -- rerun's own RuntimeError: the file writer stopped (disk full)
                self.recording_failed = f"--save {self.save}: recording not written ({shorten(str(error), 80)})"
            finally:
                if self.recording_failed:  # flushed once and failed: detach without the observer's warning about it
                    self.rerun_observer.recording.disconnect()
                else:
                    self.rerun_observer.close()
            if tmp is not None and complete and not self.recording_failed:
                try:
                    commit_file(tmp, self.save)
                    committed = True
                except OSError as error:
                    self.recording_failed = f"--save {self.save}: recording not written ({error.strerror or error})"
        finally:  # whatever stopped it (an interrupt while flushing too): never a partial recording left anywhere
            if tmp is not None and not committed:
                with contextlib.suppress(FileNotFoundError):
                    tmp.unlink()  # an earlier FILE.rrd stays as it was
        if committed:
            size = self.save.stat().st_size
            print(f"recording written to {self.save} ({size / 1e6:.1f} MB)", file=self.out, flush=True)

    def __enter__(self) -> TelemetryObservers:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(wait=exc_type is None, complete=exc_type is None)


def telemetry_observers(
    args: argparse.Namespace, *, application_id: str = "gantry_twin", out: TextIO | None = None
) -> TelemetryObservers:
    """Observers for the telemetry options in ``args`` (empty: no telemetry).

    Checks every option before opening anything (TelemetryError, one line).
    Use as ``with telemetry_observers(args) as observers: simulate(..., observers=observers)``.
    """
    out = out or sys.stdout
    save: Path | None = getattr(args, "save", None)
    connect: str | None = getattr(args, "connect", None)
    viewer = bool(getattr(args, "viewer", False))
    serve_web = bool(getattr(args, "serve_web", False))
    realtime: float | None = getattr(args, "realtime", None)
    if save is not None:
        save = Path(save)
        if save.suffix != ".rrd":
            raise TelemetryError(f"--save: FILE must end in .rrd, got {quote(str(save))}")
        if not save.parent.is_dir():
            raise TelemetryError(f"--save: directory {quote(str(save.parent))} does not exist")
        try:  # a FIFO, device (/dev/null), socket or directory is never written to nor replaced
            check_replaceable(save)
        except NotRegularFileError as exc:
            raise TelemetryError(f"--save {save}: {exc.strerror}") from None
    if connect is not None:
        check_grpc_url(connect)
    if viewer:
        require_display()
    observers: list[Observer] = []
    rerun_observer = None
    server = None
    save_tmp: Path | None = None
    if save or connect or viewer or serve_web:
        sinks: list = []
        if serve_web:
            server = WebViewerServer()
            sinks.append(rr.GrpcSink(server.grpc_url))
            print(f"Rerun web viewer: {server.url}", file=out, flush=True)
        recording = rr.RecordingStream(application_id)
        if viewer:
            sinks.append(rr.GrpcSink(spawn_native_viewer(recording)))
        if connect:
            sinks.append(rr.GrpcSink(connect))
        try:
            if save:  # rerun writes a hidden temporary beside FILE.rrd: an earlier killed run's are removed first
                remove_stale_temporaries(save.parent)
                save_tmp = temporary_path(save)
                sinks.append(rr.FileSink(save_tmp))
            recording.set_sinks(*sinks)
        except BaseException as error:  # an interrupt too: no temporary left behind
            if server is not None:
                server.stop()
            if save_tmp is not None:
                save_tmp.unlink(missing_ok=True)
            if not isinstance(error, (RuntimeError, OSError)):
                raise
            raise TelemetryError(f"--save: cannot write {quote(str(save))}: {shorten(str(error))}") from None
        rerun_observer = RerunObserver(recording)
        observers.append(rerun_observer)
    if realtime is not None:
        observers.append(RealtimePacer(realtime))
    return TelemetryObservers(observers, rerun_observer, server, out, save, save_tmp)
