"""Screenshot of the rerun web viewer showing a recording (for docs/images/dashboard.png).

Usage: python tools/dashboard_screenshot.py RUN.rrd OUT.png [--wait SECONDS]

Serves RUN.rrd with rerun's web viewer on 127.0.0.1, opens it in headless
Chromium (software WebGL through SwiftShader) over the DevTools protocol,
waits for the viewer to load and draw, and writes a PNG. Needs `chromium`
on PATH and the `websockets` package.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import json
import subprocess
import sys
import tempfile
import time
import urllib.parse
import urllib.request

import websockets

from gantry_twin.telemetry import LOCALHOST, TelemetryError, WebViewerServer, free_port


async def _capture(ws_url: str, page_url: str, wait_s: float, width: int, height: int) -> bytes:
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
        await call("Page.navigate", url=page_url)
        await asyncio.sleep(wait_s)
        shot = await call("Page.captureScreenshot", format="png")
        return base64.b64decode(shot["data"])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording")
    parser.add_argument("out")
    parser.add_argument("--wait", type=float, default=40.0, help="seconds to let the viewer load (default 40)")
    parser.add_argument("--size", default="1600x1000")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
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
        png = asyncio.run(_capture(pages[0]["webSocketDebuggerUrl"], page_url, args.wait, width, height))
        with open(args.out, "wb") as f:
            f.write(png)
        print(f"wrote {args.out} ({len(png)} bytes)")
        return 0
    finally:
        if browser is not None and browser.poll() is None:
            browser.terminate()
            browser.wait(timeout=10)
        server.stop()


if __name__ == "__main__":
    sys.exit(main())
