"""Live rerun dashboard and recordings of a run (rerun-sdk 0.41); docs/telemetry.md.

    observer.py    RerunObserver: logs a run to its own recording, chunk by chunk (what is logged, where)
    dashboard.py   the default blueprint and the gantry's bodies in 3D, read from the compiled model
    sinks.py       native viewer, local web viewer, URL checks, RealtimePacer
    options.py     --viewer/--save/--connect/--serve-web/--realtime and the observers they ask for

Python::

    from gantry_twin.telemetry import RerunObserver
    with RerunObserver.to_file("run.rrd") as observer:   # or .spawn_viewer(), .connect(url)
        trace = simulate(..., observers=[observer])

Command line: ``gantry-twin run SCENARIO --serve-web`` (or --viewer, --save FILE.rrd, --connect URL).
"""

from gantry_twin.telemetry.dashboard import (
    ERROR_MAGNIFICATION,
    TIMELINE,
    BodyBoxes,
    dashboard_blueprint,
    gantry_bodies,
    magnified_contour_m,
)
from gantry_twin.telemetry.observer import (
    CONTOUR_RATE_HZ,
    ESTIMATE_RATE_HZ,
    MARKER_RATE_HZ,
    RerunObserver,
    theta_entity,
    unit_in_entity,
)
from gantry_twin.telemetry.sinks import (
    LOCALHOST,
    RealtimePacer,
    TelemetryError,
    WebViewerServer,
    check_grpc_url,
    free_port,
    has_display,
    local_grpc_url,
    require_display,
    rerun_binary,
    spawn_native_viewer,
    wait_for_port,
)

__all__ = [
    "CONTOUR_RATE_HZ",
    "ERROR_MAGNIFICATION",
    "ESTIMATE_RATE_HZ",
    "LOCALHOST",
    "MARKER_RATE_HZ",
    "TIMELINE",
    "BodyBoxes",
    "RealtimePacer",
    "RerunObserver",
    "TelemetryError",
    "WebViewerServer",
    "check_grpc_url",
    "dashboard_blueprint",
    "free_port",
    "gantry_bodies",
    "has_display",
    "local_grpc_url",
    "magnified_contour_m",
    "require_display",
    "rerun_binary",
    "spawn_native_viewer",
    "theta_entity",
    "unit_in_entity",
    "wait_for_port",
]
