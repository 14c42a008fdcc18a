"""What every request passes before any route runs (pure ASGI middleware, outermost first):

    SafetyHeaders   nosniff, DENY framing, a default-deny CSP on what has none of its own
    TrustedHost     the Host header must be one of ours (Starlette's): 400 otherwise, so a
                    DNS-rebinding page cannot talk to the server as if it were its own Origin
    BodyGuard       a body above the limit is 413 on its headers (Content-Length) or as soon as
                    it passes the limit (chunked), never read further; a body sent to anything
                    but the two login routes needs a login first (401 before a byte of it is
                    read or parsed); the answer closes the connection, so the rest is not read

The login BodyGuard finds is kept on the request (``scope["state"]["identity"]``) and reused
by :func:`server.api.deps.current_account`, which still decides what the account may do.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from starlette.datastructures import Headers
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import HTTPConnection
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from server.security import identify_async
from server.settings import Settings

# Routes that take a body from someone not logged in yet, and the most they need.
PUBLIC_BODIES: frozenset[str] = frozenset({"/api/v1/auth/login", "/api/v1/auth/token"})
PUBLIC_BODY_MAX = 4096  # bytes: a login name and a password (LoginIn's own bounds)

# For responses that bring no policy of their own (the API's JSON, errors): nothing to run.
DEFAULT_CSP = "default-src 'none'; frame-ancestors 'none'; base-uri 'none'; form-action 'none'"


def _refusal(status: int, detail: str, extra: Sequence[tuple[bytes, bytes]]) -> list[Message]:
    body = ('{"detail":"' + detail + '"}').encode()
    headers = [
        (b"content-type", b"application/json"),
        (b"content-length", str(len(body)).encode()),
        (b"connection", b"close"),  # the rest of the body is never read
        *extra,
    ]
    return [
        {"type": "http.response.start", "status": status, "headers": headers},
        {"type": "http.response.body", "body": body},
    ]


class BodyGuard:
    """The body limit and the login a body needs, before the body is read."""

    def __init__(self, app: ASGIApp, max_body: int) -> None:
        self.app = app
        self.max_body = max_body

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        chunked = "chunked" in headers.get("transfer-encoding", "").lower()
        try:
            length = int(headers.get("content-length", "0") or 0)
        except ValueError:
            length = -1
        if not chunked and length == 0:
            await self.app(scope, receive, send)
            return
        public = scope["path"] in PUBLIC_BODIES
        limit = PUBLIC_BODY_MAX if public else self.max_body
        if length < 0:
            return await self._refuse(send, 400, "invalid Content-Length")
        if length > limit:
            return await self._refuse(send, 413, f"request body over {limit} bytes")
        if not public:
            identity = await identify_async(HTTPConnection(scope), scope["app"].state.runtime.store)
            if identity[0] is None:
                why = "not logged in" if identity[1] == "none" else "login expired or revoked"
                extra = [(b"www-authenticate", b"Bearer")]
                return await self._refuse(send, 401, why, extra)
            scope.setdefault("state", {})["identity"] = identity
        await self._limited(scope, receive, send, limit)

    async def _refuse(
        self, send: Send, status: int, detail: str, extra: Sequence[tuple[bytes, bytes]] = ()
    ) -> None:
        for message in _refusal(status, detail, extra):
            await send(message)

    async def _limited(self, scope: Scope, receive: Receive, send: Send, limit: int) -> None:
        """The app, with a receive that stops at ``limit`` bytes: past it, 413 (if nothing
        was answered yet) and the app sees the client gone; anything it sends after is dropped."""
        seen = 0
        state: dict[str, bool] = {"started": False, "refused": False}

        async def limited_receive() -> Message:
            nonlocal seen
            if state["refused"]:
                return {"type": "http.disconnect"}
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:
                    state["refused"] = True
                    if not state["started"]:
                        await self._refuse(send, 413, f"request body over {limit} bytes")
                    return {"type": "http.disconnect"}
            return message

        async def guarded_send(message: Message) -> None:
            if state["refused"]:
                return
            if message["type"] == "http.response.start":
                state["started"] = True
            await send(message)

        await self.app(scope, limited_receive, guarded_send)


class SafetyHeaders:
    """Headers every response carries unless it set its own (the dashboard's page sets its
    CSP; /docs its own): no MIME sniffing, no framing, a default-deny CSP."""

    DEFAULTS: tuple[tuple[bytes, bytes], ...] = (
        (b"x-content-type-options", b"nosniff"),
        (b"x-frame-options", b"DENY"),
        (b"referrer-policy", b"same-origin"),
        (b"content-security-policy", DEFAULT_CSP.encode()),
    )

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers: list[Any] = list(message.get("headers", []))
                have = {bytes(k).lower() for k, _ in headers}
                headers += [(k, v) for k, v in self.DEFAULTS if k not in have]
                message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, with_headers)


def install(app: Any, settings: Settings) -> None:
    """The guards on ``app``, the outermost last (Starlette wraps each added one around)."""
    app.add_middleware(BodyGuard, max_body=settings.max_body_bytes)
    app.add_middleware(
        TrustedHostMiddleware, allowed_hosts=settings.host_names(), www_redirect=False
    )
    app.add_middleware(SafetyHeaders)
