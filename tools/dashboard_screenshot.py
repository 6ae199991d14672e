"""Screenshot of the rerun web viewer showing a recording (for docs/images/dashboard.png).

Usage: python tools/dashboard_screenshot.py RUN.rrd OUT.png [--wait SECONDS] [--settle N] [--timeout SECONDS]

Serves RUN.rrd with rerun's web viewer on 127.0.0.1, opens it in headless
Chromium (software WebGL through SwiftShader) over the DevTools protocol,
and captures the page every --interval seconds from --wait on, until N
captures in a row are identical (the viewer has loaded the recording and
stopped drawing) or --timeout. A fixed wait was not enough: on a busy
2-core machine the viewer showed the layout with empty plots for about two
minutes before the data arrived, and the page changes while it loads. Look
at the result: a viewer that is stuck also stops changing. Needs `chromium`
on PATH and the `websockets` package.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import json
import signal
import subprocess
import sys
import tempfile
import time
import urllib.parse
import urllib.request

import websockets

from gantry_twin.telemetry import LOCALHOST, TelemetryError, WebViewerServer, free_port


async def _capture(
    ws_url: str, page_url: str, wait_s: float, interval_s: float, settle: int, timeout_s: float, width: int, height: int
) -> tuple[bytes, float, bool]:
    """The page once ``settle`` captures in a row are identical (or at ``timeout_s``): (PNG, seconds, settled)."""
    async with websockets.connect(ws_url, max_size=64 * 1024 * 1024) as ws:
        ids = iter(range(1, 1_000_000))

        async def call(method: str, **params) -> dict:
            message_id = next(ids)
            await ws.send(json.dumps({"id": message_id, "method": method, "params": params}))
            while True:
                reply = json.loads(await ws.recv())
                if reply.get("id") == message_id:
                    return reply.get("result", {})

        await call("Emulation.setDeviceMetricsOverride", width=width, height=height, deviceScaleFactor=1, mobile=False)
        started = time.monotonic()
        await call("Page.navigate", url=page_url)
        await asyncio.sleep(wait_s)
        previous, same = b"", 0
        while True:
            png = base64.b64decode((await call("Page.captureScreenshot", format="png"))["data"])
            same = same + 1 if png == previous else 1
            previous = png
            elapsed = time.monotonic() - started
            if same >= settle or elapsed >= timeout_s:
                return png, elapsed, same >= settle
            await asyncio.sleep(interval_s)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording")
    parser.add_argument("out")
    parser.add_argument("--wait", type=float, default=30.0, help="seconds before the first capture (default 30)")
    parser.add_argument("--interval", type=float, default=10.0, help="seconds between captures (default 10)")
    parser.add_argument("--settle", type=int, default=3, help="identical captures in a row that end it (default 3)")
    parser.add_argument("--timeout", type=float, default=600.0, help="give up waiting after this (default 600 s)")
    parser.add_argument("--size", default="1600x1000")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    # SIGTERM and SIGHUP unwind like Ctrl-C, so that the browser and the viewer's server are stopped (finally).
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, lambda number, frame: sys.exit(128 + number))
    debug_port = free_port()
    try:
        server = WebViewerServer(timeout_s=30.0, recordings=[args.recording])
    except TelemetryError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    page_url = server.url
    browser = None
    try:
        browser = subprocess.Popen(
            [
                "chromium",
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-quic",
                "--no-first-run",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader",
                f"--user-data-dir={tempfile.mkdtemp()}",
                f"--window-size={width},{height}",
                f"--remote-debugging-address={LOCALHOST}",
                f"--remote-debugging-port={debug_port}",
                "about:blank",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        deadline = time.monotonic() + 30
        while True:
            try:
                with urllib.request.urlopen(f"http://{LOCALHOST}:{debug_port}/json/list", timeout=2) as reply:
                    pages = [p for p in json.load(reply) if p.get("type") == "page"]
                if pages:
                    break
            except OSError:
                pass
            if time.monotonic() > deadline:
                print("error: chromium did not start", file=sys.stderr)
                return 1
            time.sleep(0.3)
        png, elapsed_s, settled = asyncio.run(
            _capture(
                pages[0]["webSocketDebuggerUrl"],
                page_url,
                args.wait,
                args.interval,
                args.settle,
                args.timeout,
                width,
                height,
            )
        )
        with open(args.out, "wb") as f:
            f.write(png)
        how = "unchanged over the last captures" if settled else "still changing at --timeout: look at it"
        print(f"wrote {args.out} ({len(png)} bytes) after {elapsed_s:.0f} s, {how}")
        return 0 if settled else 3
    finally:
        if browser is not None and browser.poll() is None:
            browser.terminate()
            browser.wait(timeout=10)
        server.stop()


if __name__ == "__main__":
    sys.exit(main())
