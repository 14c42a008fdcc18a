"""Who is asking, and may they: logins, roles, failed-login limits, Origin checks.

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
from collections.abc import Awaitable, Callable
from typing import Annotated, Literal

from fastapi import Depends, HTTPException, Request, WebSocket, status

from sessions.store import AccountRecord, Role, Store

COOKIE = "ergoseek_session"
RANK: dict[str, int] = {"viewer": 0, "trainer": 1, "admin": 2}
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


def own_origins(request: Request | WebSocket, extra: list[str]) -> set[str]:
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
    request: Request | WebSocket, store: Store
) -> tuple[AccountRecord | None, Literal["bearer", "cookie", "none"]]:
    """The account behind a request and how it proved it (bearer token first)."""
    token = bearer(request)
    if token is not None:
        return store.tokens.resolve(token), "bearer"
    cookie = request.cookies.get(COOKIE)
    if cookie:
        return store.tokens.resolve(cookie), "cookie"
    return None, "none"


def unauthorized(detail: str = "not logged in") -> HTTPException:
    return HTTPException(
        status.HTTP_401_UNAUTHORIZED, detail=detail, headers={"WWW-Authenticate": "Bearer"}
    )


async def current_account(request: Request) -> AccountRecord:
    """The logged-in account; 401 otherwise, 403 for a cross-site change by cookie."""
    runtime = request.app.state.runtime
    account, how = await asyncio.to_thread(identify, request, runtime.store)
    if account is None:
        raise unauthorized("not logged in" if how == "none" else "login expired or revoked")
    if (
        how == "cookie"
        and request.method not in SAFE_METHODS
        and not origin_allowed(request, runtime.settings.allowed_origins)
    ):
        raise HTTPException(status.HTTP_403_FORBIDDEN, detail="cross-site request refused")
    request.state.account = account
    return account


def require(role: Role) -> Callable[[AccountRecord], Awaitable[AccountRecord]]:
    """A dependency: the account, if its role is at least ``role`` (else 403)."""

    async def check(account: Annotated[AccountRecord, Depends(current_account)]) -> AccountRecord:
        if RANK[account.role] < RANK[role]:
            raise HTTPException(
                status.HTTP_403_FORBIDDEN, detail=f"needs the {role} role (you are {account.role})"
            )
        return account

    return check


Viewer = Annotated[AccountRecord, Depends(require("viewer"))]
Trainer = Annotated[AccountRecord, Depends(require("trainer"))]
Admin = Annotated[AccountRecord, Depends(require("admin"))]


def retry_after_header(seconds: float) -> dict[str, str]:
    return {"Retry-After": str(max(1, math.ceil(seconds)))}
