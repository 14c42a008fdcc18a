"""The dashboard's HTTP side: the login page at ``/``, viser's built client at ``/dashboard/``
(logged-in accounts only; gzipped when the browser accepts it) and the proxied WebSocket at
``/dashboard``.

The viser client derives its WebSocket URL from the page's location with the trailing ``/``
stripped, so the page at ``/dashboard/`` connects to ``/dashboard``.
"""

from __future__ import annotations

import asyncio
import functools
import gzip
from pathlib import Path

import viser
from fastapi import APIRouter, Request, WebSocket
from fastapi.responses import HTMLResponse, RedirectResponse, Response

from server.api.deps import RuntimeDep
from server.runtime import Runtime
from server.security import COOKIE, identify
from sessions.store import AccountRecord
from webui import csp, login_page
from webui.proxy import dashboard_socket

router = APIRouter(include_in_schema=False)

CLIENT_BUILD = Path(viser.__file__).resolve().parent / "client" / "build"
HEADERS = {
    "Cache-Control": "no-store",
    "X-Frame-Options": "DENY",  # nobody frames a page with an E-STOP
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "same-origin",
}
# The policies (webui.csp): viser's page may run its two scripts and nothing else, talk to
# this origin only (viser's client would follow ``?websocket=URL`` to any server: a fake
# machine); the login page its one script. Neither may be framed.
NO_PAGE = {**HEADERS, "Content-Security-Policy": "default-src 'none'; frame-ancestors 'none'"}


LOGIN_POLICY = csp.page_policy(login_page.render(None))


def dashboard_headers() -> dict[str, str]:
    return {**HEADERS, "Content-Security-Policy": csp.dashboard_policy()}


TYPES = {
    ".html": "text/html; charset=utf-8",
    ".js": "application/javascript",
    ".css": "text/css; charset=utf-8",
    ".svg": "image/svg+xml",
    ".png": "image/png",
    ".wasm": "application/wasm",
    ".json": "application/json",
    ".hdr": "application/octet-stream",
}


@functools.lru_cache(maxsize=16)
def _asset(relpath: str) -> tuple[bytes, bytes, str] | None:
    """(raw, gzipped, content type) of a file of viser's built client, or None."""
    parts = [p for p in relpath.split("/") if p and p != "."]
    if any(p == ".." or "\\" in p for p in parts):
        return None
    path = CLIENT_BUILD.joinpath(*parts) if parts else CLIENT_BUILD / "index.html"
    if not path.is_file() or CLIENT_BUILD not in path.resolve().parents:
        return None
    raw = path.read_bytes()
    kind = TYPES.get(path.suffix.lower(), "application/octet-stream")
    return raw, gzip.compress(raw, 6), kind


def _serve(request: Request, relpath: str) -> Response:
    found = _asset(relpath)
    if found is None:
        return Response(status_code=404, headers=NO_PAGE)
    raw, zipped, kind = found
    headers = {**dashboard_headers(), "Vary": "Accept-Encoding"}
    if "gzip" in request.headers.get("accept-encoding", ""):
        return Response(zipped, media_type=kind, headers={**headers, "Content-Encoding": "gzip"})
    return Response(raw, media_type=kind, headers=headers)


async def _account(request: Request, runtime: Runtime) -> AccountRecord | None:
    if not request.cookies.get(COOKIE):
        return None
    account, _ = await asyncio.to_thread(identify, request, runtime.store)
    return account


@router.get("/", response_class=HTMLResponse)
async def login(request: Request, runtime: RuntimeDep) -> HTMLResponse:
    account = None if "logout" in request.query_params else await _account(request, runtime)
    who = f"{account.login} ({account.role})" if account is not None else None
    page = login_page.render(who)
    return HTMLResponse(page, headers={**HEADERS, "Content-Security-Policy": LOGIN_POLICY})


@router.get("/dashboard")
async def dashboard_no_slash() -> RedirectResponse:
    return RedirectResponse("/dashboard/", status_code=307)


@router.get("/dashboard/{relpath:path}")
async def dashboard(request: Request, relpath: str, runtime: RuntimeDep) -> Response:
    if await _account(request, runtime) is None:
        return RedirectResponse("/", status_code=303, headers={"Cache-Control": "no-store"})
    if runtime.dashboard is None:
        return Response("the dashboard is not running", status_code=503, headers=NO_PAGE)
    return await asyncio.to_thread(_serve, request, relpath)


@router.websocket("/dashboard")
async def dashboard_ws(ws: WebSocket, runtime: RuntimeDep) -> None:
    await dashboard_socket(ws, runtime)
