"""The lab dashboard at ``/``: one server-rendered page, a small script that reads ``/v1``.

The page is HTML the server renders with :class:`string.Template` (title, API prefix, asset
URLs carrying a hash of their content so a new release is never mixed with a cached
script); every lab datum comes from the JSON API, fetched by ``static/dashboard.js`` with
the lab's key, which lives in the tab's ``sessionStorage`` and travels only in the
``Authorization`` header. The page therefore holds no lab data and needs no session or
cookie on the server. Every asset is served from :data:`STATIC_URL` (no CDN, no build step);
the Content-Security-Policy makes the browser refuse anything else.
"""

from __future__ import annotations

import hashlib
from functools import cache
from pathlib import Path
from string import Template

from fastapi import APIRouter, Request
from fastapi.responses import HTMLResponse

from service.api.routes.apidocs import ASSETS_URL

STATIC_DIR = Path(__file__).parents[1] / "static"
STATIC_URL = "/static/dashboard"
TEMPLATE = Path(__file__).parents[1] / "templates" / "dashboard.html"

# Scripts, styles, data and images from this server only; images also from blob: URLs (results
# fetched with the key); no framing (clickjacking), no form posting elsewhere.
SECURITY_HEADERS = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' blob: data:; object-src 'none'; "
                               "base-uri 'none'; form-action 'self'; frame-ancestors 'none'",
    "Referrer-Policy": "no-referrer",
    "X-Content-Type-Options": "nosniff",
    "Cache-Control": "no-cache",
}

router = APIRouter(include_in_schema=False)


@router.get("/", response_class=HTMLResponse)
def dashboard(request: Request) -> HTMLResponse:
    return HTMLResponse(_page(request.scope.get("root_path", "")), headers=SECURITY_HEADERS)


@cache
def _page(root: str) -> str:
    """The page for an app mounted at ``root`` (``""`` unless behind a prefixing proxy)."""
    return Template(TEMPLATE.read_text()).substitute(
        title="mocap lab dashboard", api=f"{root}/v1", docs=f"{root}/docs", redoc=f"{root}/redoc",
        css=_asset(root, "dashboard.css"), js=_asset(root, "dashboard.js"),
        favicon=f"{root}{ASSETS_URL}/favicon.png",
    )


def _asset(root: str, name: str) -> str:
    version = hashlib.sha256((STATIC_DIR / name).read_bytes()).hexdigest()[:12]
    return f"{root}{STATIC_URL}/{name}?v={version}"
