"""Headless Chromium for page tests, driven over the DevTools protocol (websockets, no extra package).

``CHROMIUM`` is the browser binary or None (Debian: ``apt-get install chromium``; ``make test``
installs it where apt runs as root). :class:`Browser` opens a page, evaluates JavaScript and takes
screenshots; the browser process is ended when the ``with`` block exits.
"""
from __future__ import annotations

import base64
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

from typing_extensions import Self

CHROMIUM = next((p for p in (shutil.which("chromium"), shutil.which("chromium-browser"),
                             shutil.which("google-chrome")) if p), None)
SKIP_REASON = "headless Chromium is not installed (apt-get install chromium); `make test` installs it as root"


class Browser:
    """``with Browser(1000, 700) as b: b.open(url); png = b.screenshot()``."""

    def __init__(self, width: int = 1000, height: int = 700, timeout: float = 30.0):
        self.width, self.height, self.timeout = width, height, timeout
        self._id = 0

    def __enter__(self) -> Self:
        from websockets.sync.client import connect

        self._dir = tempfile.TemporaryDirectory(prefix="arcsem-chromium-")
        args = [CHROMIUM, "--headless=new", "--no-sandbox", "--disable-gpu", "--no-first-run",
                "--enable-unsafe-swiftshader",  # software WebGL asked for, not left to the deprecated automatic fallback
                "--disable-extensions", "--remote-debugging-port=0", f"--user-data-dir={self._dir.name}",
                f"--window-size={self.width},{self.height}", "about:blank"]
        # its own process group: the renderer, GPU and crash-handler children end with it, before its profile folder
        # is removed (one of them still writing there made the removal fail: "Directory not empty: 'Default'")
        # TMPDIR inside the profile folder: Chromium's singleton folders (/tmp/org.chromium.Chromium.*, left behind by
        # a signalled browser) go where the folder's removal takes them
        self.proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
                                     env={**os.environ, "TMPDIR": self._dir.name})
        port_file = Path(self._dir.name) / "DevToolsActivePort"
        deadline = time.monotonic() + self.timeout
        while not (port_file.is_file() and port_file.read_text().strip()):
            if time.monotonic() > deadline or self.proc.poll() is not None:
                self._close()
                raise RuntimeError("headless Chromium did not start")
            time.sleep(0.1)
        port = int(port_file.read_text().split()[0])
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as r:
            page = next(t for t in json.loads(r.read()) if t["type"] == "page")
        self.ws = connect(page["webSocketDebuggerUrl"], max_size=64 * 2**20, open_timeout=10)
        self.call("Emulation.setDeviceMetricsOverride", width=self.width, height=self.height,
                  deviceScaleFactor=1, mobile=False)
        return self

    def __exit__(self, *exc) -> None:
        self._close()

    def _close(self) -> None:
        if getattr(self, "ws", None) is not None:
            self.ws.close()
        for sig in (signal.SIGTERM, signal.SIGKILL):
            try:
                os.killpg(self.proc.pid, sig)
            except ProcessLookupError:  # the group is gone
                break
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                continue
            time.sleep(0.2)  # the children leave after the browser process
        for attempt in range(20):  # a child that outlived the group signal can still be closing files
            try:
                self._dir.cleanup()
                break
            except OSError:
                if attempt == 19:
                    raise
                time.sleep(0.25)

    def call(self, method: str, **params) -> dict:
        """Send one DevTools command and return its result (events in between are skipped)."""
        self._id += 1
        self.ws.send(json.dumps({"id": self._id, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv(timeout=self.timeout))
            if msg.get("id") == self._id:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})

    def open(self, url: str, settle: float = 0.5) -> None:
        """Navigate and wait for the load event (then ``settle`` seconds)."""
        self.call("Page.enable")
        self.call("Page.navigate", url=url)
        deadline = time.monotonic() + self.timeout
        while self.evaluate("document.readyState") != "complete":
            if time.monotonic() > deadline:
                raise TimeoutError(f"{url} did not load")
            time.sleep(0.1)
        time.sleep(settle)

    def evaluate(self, expression: str):
        """The value of a JavaScript expression in the page."""
        res = self.call("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        return res.get("result", {}).get("value")

    def screenshot(self, path: str | Path | None = None, full_page: bool = False) -> bytes:
        """PNG bytes of the viewport (or the whole page), also written to ``path`` if given."""
        params = {"format": "png"}
        if full_page:
            size = self.call("Page.getLayoutMetrics")["cssContentSize"]
            params.update(captureBeyondViewport=True, clip={"x": 0, "y": 0, "width": size["width"],
                                                            "height": size["height"], "scale": 1})
        png = base64.b64decode(self.call("Page.captureScreenshot", **params)["data"])
        if path is not None:
            Path(path).write_bytes(png)
        return png
