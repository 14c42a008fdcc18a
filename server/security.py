"""Who is asking: logins, failed-login limits, Origin checks. (The API's role checks are
dependencies built on these: :mod:`server.api.deps`; the dashboard's proxy uses them too.)

- Browsers log in at ``POST /api/v1/auth/login`` and get an HttpOnly, SameSite=Strict cookie;
  API clients get a bearer token at ``POST /api/v1/auth/token``. Both are random tokens whose
  SHA-256 digest the store keeps (:mod:`sessions.store.tokens`); passwords are argon2 hashes.
- Roles nest: viewer (reads) ⊂ trainer (users, sessions, the machine) ⊂ admin (accounts).
- Failed logins are limited per client address and login name (``login_attempts`` in
  ``login_window_s``; four times that per address): past the limit, 429 with Retry-After,
  even for the right password.
- A request authenticated by cookie that changes something, and every WebSocket, must come
  from an allowed Origin (the server's own, or ``allowed_origins``): a cookie is sent with
  cross-site requests, a bearer token is not.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections import defaultdict, deque
from concurrent.futures import ThreadPoolExecutor
from typing import Literal

from fastapi import HTTPException, Request, WebSocket, status
from starlette.requests import HTTPConnection

from sessions.store import AccountRecord, Store

COOKIE = "ergoseek_session"
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})


class LoginLimiter:
    """Sliding-window count of failed logins: ``attempts`` per client address and login name,
    four times as many per client address whatever the name (guessing across accounts)."""

    PER_ADDRESS = 4

    def __init__(self, attempts: int, window_s: float) -> None:
        self.attempts = attempts
        self.window = window_s
        self._failures: dict[str, deque[float]] = defaultdict(deque)

    def _limit(self, key: str) -> int:
        return self.attempts * (self.PER_ADDRESS if key.startswith("addr:") else 1)

    def _recent(self, key: str, now: float) -> deque[float]:
        q = self._failures[key]
        while q and q[0] <= now - self.window:
            q.popleft()
        return q

    def retry_after(self, keys: list[str]) -> float:
        """Seconds until a login may be tried again (0: now)."""
        now = time.monotonic()
        wait = 0.0
        for key in keys:
            q = self._recent(key, now)
            if len(q) >= self._limit(key):
                wait = max(wait, q[-self._limit(key)] + self.window - now)
        return wait

    def failed(self, keys: list[str]) -> None:
        now = time.monotonic()
        for key in keys:
            self._recent(key, now).append(now)

    def succeeded(self, keys: list[str]) -> None:
        for key in keys:
            if not key.startswith("addr:"):  # a success forgives this name, not the address
                self._failures.pop(key, None)


def client_keys(request: Request | WebSocket, login: str) -> list[str]:
    host = request.client.host if request.client else "?"
    return [f"addr:{host}", f"addr+login:{host}:{login.strip().lower()}"]


def own_origins(request: Request | WebSocket | HTTPConnection, extra: list[str]) -> set[str]:
    """Origins that count as the server itself: its Host header under http and https."""
    host = request.headers.get("host", "")
    return {f"http://{host}", f"https://{host}", *extra}


def origin_allowed(request: Request | WebSocket, extra: list[str]) -> bool:
    """No Origin (not a browser) or one of ours."""
    origin = request.headers.get("origin")
    return origin is None or origin in own_origins(request, extra)


def bearer(request: Request | WebSocket) -> str | None:
    header = request.headers.get("authorization", "")
    scheme, _, token = header.partition(" ")
    return token.strip() if scheme.lower() == "bearer" and token.strip() else None


def identify(
    request: Request | WebSocket | HTTPConnection, store: Store
) -> tuple[AccountRecord | None, Literal["bearer", "cookie", "none"]]:
    """The account behind a request and how it proved it (bearer token first)."""
    token = bearer(request)
    if token is not None:
        return store.tokens.resolve(token), "bearer"
    cookie = request.cookies.get(COOKIE)
    if cookie:
        return store.tokens.resolve(cookie), "cookie"
    return None, "none"


# The login checks' own threads: a store lookup each, never queued behind the default pool's
# work (password hashing, telemetry exports), so an e-stop's login check is never waited for.
_AUTH_POOL = ThreadPoolExecutor(max_workers=2, thread_name_prefix="ergoseek-auth")


async def identify_async(
    conn: Request | WebSocket | HTTPConnection, store: Store
) -> tuple[AccountRecord | None, Literal["bearer", "cookie", "none"]]:
    """:func:`identify` on the login checks' own threads (the store lookup blocks)."""
    if bearer(conn) is None and not conn.cookies.get(COOKIE):
        return None, "none"  # nothing to look up
    return await asyncio.get_running_loop().run_in_executor(_AUTH_POOL, identify, conn, store)


def cookie_write_allowed(request: Request | HTTPConnection, extra: list[str]) -> bool:
    """A change made with the login cookie: only with an Origin, and one of ours (a browser
    always sends Origin on a cross-origin or non-GET fetch; a request without one is not from
    our page, whatever its Referer says)."""
    origin = request.headers.get("origin")
    return origin is not None and origin in own_origins(request, extra)


def unauthorized(detail: str = "not logged in") -> HTTPException:
    return HTTPException(
        status.HTTP_401_UNAUTHORIZED, detail=detail, headers={"WWW-Authenticate": "Bearer"}
    )


def retry_after_header(seconds: float) -> dict[str, str]:
    return {"Retry-After": str(max(1, math.ceil(seconds)))}
