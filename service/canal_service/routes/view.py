"""/skills/{name}/view and /viewer/: look at a skill in a browser, with Rerun's web viewer.

``GET /skills/{name}/view`` redirects to ``/viewer/?url=<this service>/skills/{name}/recording.rrd``:
Rerun's own web viewer (HTML + JS + Wasm, the one bundled in the pinned rerun-sdk wheel),
served by this service from its own origin, opens the skill's recording snapshot. Same
origin means no CORS and one port to forward (``ssh -L 8000:127.0.0.1:8000 robot-pc``).

The viewer's files live inside the ``rerun`` binary. The first request copies them out: it
starts ``rerun --serve-web --bind 127.0.0.1`` on free loopback ports (analytics off, its own
config folder), downloads the few files the page loads, stops it, and keeps them under
``DATA_DIR/viewer/rerun-<version>/``. Later requests (and restarts) serve that folder.

The page is private and works offline: Rerun's ``index.html`` is served without its web-font
links (Google Fonts) and its analytics snippet, with a first script that refuses requests to
any other origin before they leave the browser (the viewer's usage analytics and its check for
a newer release on GitHub). The viewer falls back to its bundled fonts and runs unchanged.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from importlib import metadata
from pathlib import Path
from typing import Any
from urllib.parse import urlencode

from fastapi import APIRouter, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, HTMLResponse, RedirectResponse

from canal_protocol.schemas import ErrorResponse

from ..core.config import Settings
from ..deps import ServiceDep, SkillName
from ..errors import Disabled, NotFound

router = APIRouter(tags=["view"])

# What the bundled index.html loads (checked against rerun-sdk 0.41.0); the page is index.html.
ASSETS: dict[str, str] = {
    "index.html": "text/html; charset=utf-8",
    "re_viewer.js": "text/javascript",
    "re_viewer_bg.wasm": "application/wasm",
    "favicon.ico": "image/x-icon",
    "apple-touch-icon.png": "image/png",
}
REQUIRED = ("index.html", "re_viewer.js", "re_viewer_bg.wasm")
START_TIMEOUT_S = 60.0
_lock = threading.Lock()


#: Runs before the viewer's own scripts: ``fetch`` and ``sendBeacon`` to another origin fail at
#: once, so nothing leaves the page for hosts other than this service.
OWN_ORIGIN_ONLY = """<script>
(function () {
  var own = window.location.origin;
  function foreign(target) {
    var url = new URL(target instanceof Request ? target.url : String(target), window.location.href);
    return url.origin !== own && url.protocol !== "blob:" && url.protocol !== "data:";
  }
  var fetchOwn = window.fetch.bind(window);
  window.fetch = function (target, init) {
    if (foreign(target)) {
      return Promise.reject(new TypeError("not fetched: this page loads from its own service only"));
    }
    return fetchOwn(target, init);
  };
  if (navigator.sendBeacon) {
    var beaconOwn = navigator.sendBeacon.bind(navigator);
    navigator.sendBeacon = function (target, data) { return !foreign(target) && beaconOwn(target, data); };
  }
})();
</script>"""
_EXTERNAL_LINK = re.compile(r"<link\b[^>]*\bhref=\"https?://[^>]*>\s*", re.S)
_ANALYTICS = re.compile(r"if \(window\.location\.hostname == \"app\.rerun\.io\"\) \{.*?\n\s*\}\n", re.S)


def offline_page(html: str) -> str:
    """Rerun's ``index.html`` without external links and analytics, own origin only."""
    html = _EXTERNAL_LINK.sub("", html)
    html = _ANALYTICS.sub("", html)
    return html.replace("<head>", "<head>\n" + OWN_ORIGIN_ONLY, 1)


class ViewerUnavailable(Disabled):
    """The web viewer's files could not be obtained here."""


def rerun_version() -> str:
    try:
        return metadata.version("rerun-sdk")
    except metadata.PackageNotFoundError:
        return "unknown"


def viewer_dir(data_dir: Path) -> Path:
    """Where this rerun-sdk version's web viewer files are kept."""
    return data_dir / "viewer" / f"rerun-{rerun_version()}"


def _rerun_exe() -> list[str]:
    import rerun_cli  # part of rerun-sdk, a dependency: imported here, where it is used

    exe = Path(rerun_cli.__file__).with_name("rerun.exe" if sys.platform == "win32" else "rerun")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "rerun_cli"]


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _download(base: str, folder: Path, deadline: float) -> None:
    import httpx

    with httpx.Client(base_url=base, timeout=30.0) as client:
        while True:  # wait for the server to answer
            try:
                if client.get("/").status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                raise TimeoutError("the rerun web viewer server did not start")
            time.sleep(0.1)
        for name in ASSETS:
            path = "/" if name == "index.html" else f"/{name}"
            with client.stream("GET", path) as response:
                if response.status_code != 200:
                    if name in REQUIRED:
                        raise RuntimeError(f"{name}: HTTP {response.status_code}")
                    continue
                with (folder / name).open("wb") as f:
                    for chunk in response.iter_bytes(1 << 20):
                        f.write(chunk)


def _extract(target: Path) -> None:
    """Copy the viewer's files out of the bundled ``rerun`` binary into ``target``."""
    target.parent.mkdir(parents=True, exist_ok=True)
    config_home = target.parent / ".rerun-config"
    env = dict(os.environ, XDG_CONFIG_HOME=str(config_home), RERUN_TELEMETRY_ENABLED="false")
    exe = _rerun_exe()
    if not (config_home / "rerun" / "analytics.json").exists():
        config_home.mkdir(parents=True, exist_ok=True)
        subprocess.run([*exe, "analytics", "disable"], env=env, capture_output=True,
                       timeout=60, check=False)
    staging = Path(tempfile.mkdtemp(prefix=".staging-", dir=target.parent))
    try:
        web, grpc = _free_port(), _free_port()
        proc = subprocess.Popen(
            [*exe, "--serve-web", "--bind", "127.0.0.1", "--web-viewer-port", str(web),
             "--port", str(grpc)],
            env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL)
        try:
            _download(f"http://127.0.0.1:{web}", staging, time.monotonic() + START_TIMEOUT_S)
        finally:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(10)
        with contextlib.suppress(FileNotFoundError):
            shutil.rmtree(target)
        staging.rename(target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def ensure_viewer(data_dir: Path) -> Path:
    """The folder holding the web viewer's files, extracting them on first use."""
    target = viewer_dir(data_dir)
    if all((target / name).is_file() for name in REQUIRED):
        return target
    with _lock:
        if not all((target / name).is_file() for name in REQUIRED):
            try:
                _extract(target)
            except (OSError, RuntimeError, TimeoutError, subprocess.SubprocessError) as exc:
                raise ViewerUnavailable(
                    f"could not prepare Rerun's web viewer: {exc}; download the recording "
                    f"(GET /skills/NAME/recording.rrd) and open it with 'rerun FILE' instead",
                    field="viewer") from None
    return target


_RESPONSES: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorResponse} for code in (404, 422)
}


@router.get("/skills/{name}/view", status_code=307, response_class=RedirectResponse,
            responses={**_RESPONSES, 307: {"description": "To the web viewer page"}},
            summary="Open the skill's recording in Rerun's web viewer")
async def view_skill(name: SkillName, request: Request, service: ServiceDep) -> RedirectResponse:
    """Redirects to ``/viewer/?url=...recording.rrd``: a browser shows the skill's demos,
    canal and reproductions in Rerun's web viewer served by this service."""
    if not service.recordings_enabled:
        raise Disabled("recordings are disabled on this service", field="recordings")
    await run_in_threadpool(service.get_skill, name)  # 404 for an unknown skill
    recording = str(request.url_for("recording_rrd", name=name))
    # A path, not a URL: the Host header names the host, and a request forged with another
    # (kept by a proxy's cache) would send the browser there. The page fetches from its own
    # origin only, whatever ``url`` says.
    page = request.url_for("viewer_page").path
    return RedirectResponse(f"{page}?{urlencode({'url': recording})}", status_code=307)


@router.get("/viewer/", response_class=FileResponse, name="viewer_page",
            summary="Rerun's web viewer (index page)", responses=_RESPONSES)
async def viewer_page(request: Request) -> HTMLResponse:
    """The viewer page; ``?url=`` names the recording it opens. It loads nothing from
    other hosts (no web fonts, no analytics)."""
    path = await _asset_path(request, "index.html")
    html = await run_in_threadpool(path.read_text, encoding="utf-8")
    return HTMLResponse(offline_page(html), headers={"Cache-Control": "no-cache"})


@router.get("/viewer/{asset}", response_class=FileResponse, include_in_schema=False)
async def viewer_asset(asset: str, request: Request) -> FileResponse:
    """The files the viewer page loads (JS, Wasm, icons)."""
    return await _asset(request, asset)


async def _asset(request: Request, asset: str) -> FileResponse:
    if asset == "index.html":
        raise NotFound("the viewer page is /viewer/", field="asset")
    path = await _asset_path(request, asset)
    return FileResponse(path, media_type=ASSETS[asset], headers={"Cache-Control": "no-cache"})


async def _asset_path(request: Request, asset: str) -> Path:
    if asset not in ASSETS:
        raise NotFound(f"no viewer file {asset!r}", field="asset")
    settings: Settings = request.app.state.settings
    folder = await run_in_threadpool(ensure_viewer, settings.data_dir)
    path = folder / asset
    if not path.is_file():
        raise NotFound(f"no viewer file {asset!r}", field="asset")
    return path
