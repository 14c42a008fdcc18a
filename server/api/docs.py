"""``/docs``: Swagger UI served from this server (the assets fastapi-offline ships, no CDN),
under a policy that runs only those scripts and the page's one inline script, by its hash,
and that no other site may frame. ReDoc is not served."""

from __future__ import annotations

import base64
import hashlib
import re
from pathlib import Path

import fastapi_offline
from fastapi import APIRouter, FastAPI, Request
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles

ASSETS = Path(fastapi_offline.__file__).parent / "static"
STATIC = "/docs/static"

router = APIRouter(include_in_schema=False)


def _inline_hashes(html: str) -> list[str]:
    """CSP sources for every inline ``<script>`` of ``html``, by SHA-256."""
    out = []
    for body in re.findall(r"<script>(.*?)</script>", html, re.S):
        digest = base64.b64encode(hashlib.sha256(body.encode()).digest()).decode()
        out.append(f"'sha256-{digest}'")
    return out


def docs_page(title: str, openapi_url: str) -> tuple[bytes, str]:
    """The page and its Content-Security-Policy."""
    html = get_swagger_ui_html(
        openapi_url=openapi_url,
        title=f"{title} - API",
        swagger_js_url=f"{STATIC}/swagger-ui-bundle.js",
        swagger_css_url=f"{STATIC}/swagger-ui.css",
        swagger_favicon_url=f"{STATIC}/favicon.png",
    ).body.decode()
    csp = "; ".join(
        (
            "default-src 'none'",
            "script-src 'self' " + " ".join(_inline_hashes(html)),
            "style-src 'self'",
            "img-src 'self' data:",
            "connect-src 'self'",
            "frame-ancestors 'none'",
            "base-uri 'none'",
            "form-action 'none'",
        )
    )
    return html.encode(), csp


@router.get("/docs", response_class=HTMLResponse)
async def docs(request: Request) -> HTMLResponse:
    app = request.app
    body, csp = docs_page(app.title, app.openapi_url or "/openapi.json")
    return HTMLResponse(body, headers={"Content-Security-Policy": csp, "X-Frame-Options": "DENY"})


def mount(app: FastAPI) -> None:
    app.mount(STATIC, StaticFiles(directory=ASSETS), name="docs-static")
    app.include_router(router)
