"""/docs (Swagger UI) and /redoc (ReDoc) served from this service, with no CDN.

FastAPI's own pages load Swagger UI, ReDoc, their favicon and (ReDoc) Google Fonts from the
internet: offline they are blank, and every visit tells a CDN who reads the API. Here the pages
are FastAPI's HTML with every asset pointed at ``/docs-assets/``, served from the files the
``fastapi-offline`` package ships (Swagger UI's bundle and CSS, ReDoc's standalone bundle).
Swagger UI's schema validator badge is off, and ReDoc's side-menu logo (an image on Redocly's
CDN) is this service's icon.
"""

from __future__ import annotations

import functools
from importlib import resources
from pathlib import Path

from fastapi import APIRouter, Request
from fastapi.openapi.docs import (
    get_redoc_html,
    get_swagger_ui_html,
    get_swagger_ui_oauth2_redirect_html,
)
from fastapi.responses import FileResponse, HTMLResponse, Response

from ..errors import NotFound

router = APIRouter(include_in_schema=False)

DOCS_URL = "/docs"
REDOC_URL = "/redoc"
ASSETS_URL = "/docs-assets"
#: The files the two pages load, and their media types.
ASSETS: dict[str, str] = {
    "swagger-ui-bundle.js": "text/javascript",
    "swagger-ui.css": "text/css",
    "redoc.standalone.js": "text/javascript",
    "favicon.png": "image/png",
}
#: Swagger UI asks validator.swagger.io about the schema unless told not to.
SWAGGER_UI_PARAMETERS = {"validatorUrl": None}
#: Text replaced in a bundle as it is served: ReDoc draws Redocly's logo from its CDN.
REWRITES: dict[str, tuple[bytes, bytes]] = {
    "redoc.standalone.js": (b'src:"https://cdn.redoc.ly/redoc/logo-mini.svg"',
                            f'src:"{ASSETS_URL}/favicon.png"'.encode()),
}


def assets_dir() -> Path:
    """The installed folder holding Swagger UI's and ReDoc's files."""
    return Path(str(resources.files("fastapi_offline") / "static"))


def _prefix(request: Request) -> str:
    return str(request.scope.get("root_path", "")).rstrip("/")


@router.get(DOCS_URL)
async def swagger_ui(request: Request) -> HTMLResponse:
    root = _prefix(request)
    app = request.app
    return get_swagger_ui_html(
        openapi_url=f"{root}{app.openapi_url}",
        title=f"{app.title} - Swagger UI",
        oauth2_redirect_url=f"{root}{app.swagger_ui_oauth2_redirect_url}",
        swagger_js_url=f"{root}{ASSETS_URL}/swagger-ui-bundle.js",
        swagger_css_url=f"{root}{ASSETS_URL}/swagger-ui.css",
        swagger_favicon_url=f"{root}{ASSETS_URL}/favicon.png",
        swagger_ui_parameters={**(app.swagger_ui_parameters or {}), **SWAGGER_UI_PARAMETERS})


@router.get(f"{DOCS_URL}/oauth2-redirect")
async def swagger_ui_redirect() -> HTMLResponse:
    return get_swagger_ui_oauth2_redirect_html()


@router.get(REDOC_URL)
async def redoc(request: Request) -> HTMLResponse:
    root = _prefix(request)
    app = request.app
    return get_redoc_html(
        openapi_url=f"{root}{app.openapi_url}",
        title=f"{app.title} - ReDoc",
        redoc_js_url=f"{root}{ASSETS_URL}/redoc.standalone.js",
        redoc_favicon_url=f"{root}{ASSETS_URL}/favicon.png",
        with_google_fonts=False)


@functools.cache
def rewritten(asset: str) -> bytes:
    """``asset``'s bytes with its :data:`REWRITES` applied (read once)."""
    old, new = REWRITES[asset]
    return (assets_dir() / asset).read_bytes().replace(old, new)


@router.get(f"{ASSETS_URL}/{{asset}}", response_model=None)
async def docs_asset(asset: str) -> Response:
    if asset not in ASSETS:
        raise NotFound(f"no docs file {asset!r}", field="asset")
    headers = {"Cache-Control": "public, max-age=86400"}
    if asset in REWRITES:
        return Response(rewritten(asset), media_type=ASSETS[asset], headers=headers)
    return FileResponse(assets_dir() / asset, media_type=ASSETS[asset], headers=headers)
