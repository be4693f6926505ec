"""Headless Chromium (Debian's ``chromium``) driven over its DevTools protocol.

No driver binary: Chromium listens on a loopback DevTools port (``--remote-debugging-port=0``,
the port it chose is written to ``DevToolsActivePort`` in its fresh profile folder) and this
module speaks CDP over the page's websocket (``websocket-client``). Every URL the page asks
for is kept (``Network.requestWillBeSent``), so a test can check that a page loads only from
the service's own origin.
"""

from __future__ import annotations

import base64
import io
import json
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import websocket
from PIL import Image

#: Chromium's switches for a private, offline, headless run (no first-run pages, no
#: background downloads of components, no sync, no QUIC probes).
FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--disable-default-apps", "--disable-extensions", "--mute-audio", "--hide-scrollbars",
    # WebGL on the CPU (SwiftShader): the machines running the tests have no GPU
    "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
)


def chromium_path() -> str | None:
    """Debian's chromium (``make test`` installs it when missing), or None."""
    for name in ("chromium", "chromium-browser"):
        found = shutil.which(name)
        if found:
            return found
    return None


class Chromium:
    """One headless Chromium with one page, in a fresh profile folder removed on exit."""

    def __init__(self, width: int = 1400, height: int = 900, timeout_s: float = 60.0) -> None:
        exe = chromium_path()
        if exe is None:
            raise RuntimeError("needs Debian's chromium: `make test` installs it "
                               "(apt-get install chromium)")
        self.exe = exe
        self.width, self.height = width, height
        self.timeout_s = timeout_s
        self.requests: list[str] = []
        self.console: list[str] = []
        self._events: list[dict[str, Any]] = []
        self._next_id = 0
        self._profile = Path(tempfile.mkdtemp(prefix="canal-chromium-"))
        self._proc: subprocess.Popen[bytes] | None = None
        self._ws: websocket.WebSocket | None = None

    def __enter__(self) -> Chromium:
        self._proc = subprocess.Popen(
            [self.exe, *FLAGS, f"--user-data-dir={self._profile}",
             "--remote-debugging-address=127.0.0.1", "--remote-debugging-port=0",
             f"--window-size={self.width},{self.height}", "about:blank"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            self._connect()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._ws is not None:
            self._ws.close()
            self._ws = None
        if self._proc is not None:
            self._proc.terminate()
            try:
                self._proc.wait(10)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait(10)
            self._proc = None
        shutil.rmtree(self._profile, ignore_errors=True)

    def _connect(self) -> None:
        active = self._profile / "DevToolsActivePort"
        deadline = time.monotonic() + self.timeout_s
        while not (active.is_file() and active.read_text().strip()):
            assert self._proc is not None
            if self._proc.poll() is not None:
                raise RuntimeError(f"chromium exited with {self._proc.returncode}")
            if time.monotonic() > deadline:
                raise TimeoutError("chromium did not open its DevTools port")
            time.sleep(0.05)
        port = int(active.read_text().split()[0])
        pages = [t for t in httpx.get(f"http://127.0.0.1:{port}/json/list").json()
                 if t["type"] == "page"]
        self._ws = websocket.create_connection(pages[0]["webSocketDebuggerUrl"],
                                               timeout=self.timeout_s, suppress_origin=True)
        self.call("Network.enable")
        self.call("Page.enable")
        self.call("Runtime.enable")
        self.call("Emulation.setDeviceMetricsOverride", width=self.width, height=self.height,
                  deviceScaleFactor=1, mobile=False)

    # ---- protocol -------------------------------------------------------------------------

    def call(self, method: str, **params: Any) -> dict[str, Any]:
        """Send one command and return its result (events that arrive meanwhile are kept)."""
        assert self._ws is not None
        self._next_id += 1
        ident = self._next_id
        self._ws.send(json.dumps({"id": ident, "method": method, "params": params}))
        while True:
            message = json.loads(self._ws.recv())
            if message.get("id") == ident:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return dict(message.get("result", {}))
            self._event(message)

    def _event(self, message: dict[str, Any]) -> None:
        method = message.get("method")
        params = message.get("params", {})
        if method == "Network.requestWillBeSent":
            self.requests.append(params["request"]["url"])
        elif method == "Runtime.consoleAPICalled":
            self.console.append(" ".join(str(a.get("value", a.get("description", "")))
                                         for a in params.get("args", [])))
        self._events.append(message)

    def pump(self, seconds: float) -> None:
        """Read events for ``seconds`` (the page keeps loading meanwhile)."""
        assert self._ws is not None
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            self._ws.settimeout(left)
            try:
                self._event(json.loads(self._ws.recv()))
            except websocket.WebSocketTimeoutException:
                break
        self._ws.settimeout(self.timeout_s)

    # ---- what a test does -------------------------------------------------------------------

    def open(self, url: str) -> None:
        """Navigate and wait for the page's load event."""
        self._events.clear()
        self.call("Page.navigate", url=url)
        deadline = time.monotonic() + self.timeout_s
        while not any(e.get("method") == "Page.loadEventFired" for e in self._events):
            if time.monotonic() > deadline:
                raise TimeoutError(f"{url} did not load")
            self.pump(0.2)

    def evaluate(self, expression: str) -> Any:
        """The value of a JavaScript expression in the page (promises awaited)."""
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True,
                           awaitPromise=True)
        return result.get("result", {}).get("value")

    def screenshot(self) -> np.ndarray:
        """The page as an (H, W, 3) uint8 RGB array."""
        data = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))

    def save_screenshot(self, path: Path) -> np.ndarray:
        """Take a screenshot, write it as PNG to ``path`` and return its pixels."""
        pixels = self.screenshot()
        Image.fromarray(pixels).save(path)
        return pixels


def colour_share(pixels: np.ndarray, rgb: tuple[int, int, int], tol: int = 40) -> float:
    """Fraction of pixels within ``tol`` (per channel) of the colour ``rgb``."""
    near = np.all(np.abs(pixels.astype(np.int16) - np.asarray(rgb, np.int16)) <= tol, axis=-1)
    return float(near.mean())
