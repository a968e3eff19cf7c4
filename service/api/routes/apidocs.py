"""``/docs`` (Swagger UI) and ``/redoc`` (ReDoc) from assets this server serves itself.

FastAPI's own pages load their JavaScript, CSS, favicon and fonts from a CDN, so on a
lab network without internet access they stay blank. The same pages are built here by
FastAPI's ``get_swagger_ui_html`` / ``get_redoc_html`` with every URL pointing under
:data:`ASSETS_URL`, where the app mounts :data:`ASSETS_DIR`: the Swagger UI and ReDoc
bundles that the ``fastapi-offline`` wheel ships (only its files are used).

A Content-Security-Policy lets the browser load nothing from elsewhere: ReDoc's bundle still
shows its maker's logo from their CDN (the image hides itself when that fails), and a page
must not reach the internet, even to fail.
"""

from __future__ import annotations

import base64
import hashlib
import re
from pathlib import Path

import fastapi_offline
from fastapi import APIRouter, Request
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html
from fastapi.responses import HTMLResponse

ASSETS_DIR = Path(fastapi_offline.__file__).parent / "static"
ASSETS_URL = "/static/apidocs"

# Swagger UI's inline start-up script is allowed by its hash; both UIs set inline styles and
# draw icons from data: URLs; ReDoc's search runs in a worker made from a blob: URL.
POLICY = ("default-src 'self'; script-src 'self' {scripts}; style-src 'self' 'unsafe-inline'; "
          "img-src 'self' data:; worker-src 'self' blob:; object-src 'none'; base-uri 'none'; "
          "frame-ancestors 'none'")

router = APIRouter(include_in_schema=False)


def _openapi_url(request: Request) -> str:
    root: str = request.scope.get("root_path", "")
    url: str = request.app.openapi_url
    return root + url


def _asset(request: Request, name: str) -> str:
    return f"{request.scope.get('root_path', '')}{ASSETS_URL}/{name}"


@router.get("/docs", response_class=HTMLResponse)
def swagger_ui(request: Request) -> HTMLResponse:
    return _only_from_here(get_swagger_ui_html(
        openapi_url=_openapi_url(request), title=f"{request.app.title} API: Swagger UI",
        swagger_js_url=_asset(request, "swagger-ui-bundle.js"),
        swagger_css_url=_asset(request, "swagger-ui.css"),
        swagger_favicon_url=_asset(request, "favicon.png"),
        # No badge from the public validator service: it would be a request to the internet.
        swagger_ui_parameters={"validatorUrl": None},
    ))


@router.get("/redoc", response_class=HTMLResponse)
def redoc(request: Request) -> HTMLResponse:
    return _only_from_here(get_redoc_html(
        openapi_url=_openapi_url(request), title=f"{request.app.title} API: ReDoc",
        redoc_js_url=_asset(request, "redoc.standalone.js"),
        redoc_favicon_url=_asset(request, "favicon.png"), with_google_fonts=False,
    ))


def _only_from_here(page: HTMLResponse) -> HTMLResponse:
    """``page`` with :data:`POLICY`, its inline scripts allowed by their SHA-256."""
    scripts = re.findall(rb"<script>(.*?)</script>", page.body, flags=re.DOTALL)
    page.headers["Content-Security-Policy"] = POLICY.format(scripts=" ".join(
        f"'sha256-{base64.b64encode(hashlib.sha256(script).digest()).decode()}'" for script in scripts))
    return page
