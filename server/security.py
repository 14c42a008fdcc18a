"""Who is asking: logins, failed-login limits, Origin checks. (The API's role checks are
dependencies built on these: :mod:`server.api.deps`; the dashboard's proxy uses them too.)

- Browsers log in at ``POST /api/v1/auth/login`` and get an HttpOnly, SameSite=Strict cookie;
  API clients get a bearer token at ``POST /api/v1/auth/token``. Both are random tokens whose
  SHA-256 digest the store keeps (:mod:`sessions.store.tokens`); passwords are argon2 hashes.
- Roles nest: viewer (reads) ⊂ trainer (users, sessions, the machine) ⊂ admin (accounts).
- Failed logins are limited (``login_attempts`` in ``login_window_s``): per device cookie for
  a browser that logged in before, else per client address and login name (four times that
  per address); past the limit, 429 with Retry-After, even for the right password.
- A request authenticated by cookie that changes something, and every WebSocket, must come
  from an allowed Origin (the server's own, or ``allowed_origins``): a cookie is sent with
  cross-site requests, a bearer token is not.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import hmac
import math
import os
import secrets
import time
from collections import defaultdict, deque
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Literal

from fastapi import HTTPException, Request, WebSocket, status
from starlette.requests import HTTPConnection

from sessions.store import AccountRecord, Store

COOKIE = "ergoseek_session"
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})


DEVICE_COOKIE = "ergoseek_device"
DEVICE_COOKIE_DAYS = 365
DEVICE_KEY_FILE = "device-cookie.key"
HASHING_AT_ONCE = 2
MAX_TRACKED = 20_000  # failure keys kept at most (rotating names cannot grow memory)


def device_key(directory: Path | None) -> bytes:
    """The key that signs device cookies: kept in ``directory`` (beside the SQLite file) so
    known-good browsers stay known across restarts; without one, new for this process."""
    if directory is None:
        return secrets.token_bytes(32)
    path = directory / DEVICE_KEY_FILE
    with contextlib.suppress(FileExistsError):
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(secrets.token_bytes(32))
    key = path.read_bytes()
    return key if len(key) >= 32 else secrets.token_bytes(32)


class LoginLimiter:
    """Sliding-window count of failed logins, keyed as OWASP's *device cookies* suggest, so
    that guessing from a shared address (a NAT, a gym's Wi-Fi) cannot lock out a person who
    has logged in from their browser before:

    - a client with a valid device cookie for the login name (set at each successful login,
      signed, bound to that name) is counted on its own: ``attempts`` failures lock that
      cookie, nothing else, and nobody else's failures lock it;
    - any other client is counted per client address and login name (``attempts``) and per
      address whatever the name (four times as many: guessing across accounts).
    """

    PER_ADDRESS = 4

    def __init__(self, attempts: int, window_s: float, key: bytes | None = None) -> None:
        self.attempts = attempts
        self.window = window_s
        self._key = key or secrets.token_bytes(32)
        self._failures: dict[str, deque[float]] = defaultdict(deque)
        # password checks at a time (argon2: 64 MiB and ~0.1 s of a core each), and waiting
        self.hashing = asyncio.Semaphore(HASHING_AT_ONCE)
        self.hashing_waiting = 0

    # -- device cookies -----------------------------------------------------------------------
    def _sign(self, login: str, nonce: str) -> str:
        mac = hmac.new(self._key, f"{login}|{nonce}".encode(), hashlib.sha256)
        return mac.hexdigest()[:32]

    def device_cookie(self, login: str) -> str:
        """A new device cookie's value for ``login`` (set it after a successful login)."""
        nonce = secrets.token_urlsafe(12)
        return f"{nonce}.{self._sign(_name(login), nonce)}"

    def device(self, request: Request | WebSocket, login: str) -> str | None:
        """The device cookie's id, if the request carries a valid one for ``login``."""
        value = request.cookies.get(DEVICE_COOKIE, "")
        nonce, _, sig = value.partition(".")
        if not nonce or len(value) > 128:
            return None
        return nonce if hmac.compare_digest(sig, self._sign(_name(login), nonce)) else None

    def keys(self, request: Request | WebSocket, login: str) -> list[str]:
        """What a login attempt counts against (see the class)."""
        nonce = self.device(request, login)
        return [f"device:{nonce}"] if nonce else client_keys(request, login)

    # -- counting ----------------------------------------------------------------------------
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
            if key not in self._failures:
                continue
            q = self._recent(key, now)
            if len(q) >= self._limit(key):
                wait = max(wait, q[-self._limit(key)] + self.window - now)
        return wait

    def failed(self, keys: list[str]) -> None:
        now = time.monotonic()
        if len(self._failures) > MAX_TRACKED:
            self._sweep(now)
        for key in keys:
            self._recent(key, now).append(now)

    def succeeded(self, keys: list[str]) -> None:
        for key in keys:
            if not key.startswith("addr:"):  # a success forgives this name, not the address
                self._failures.pop(key, None)

    def _sweep(self, now: float) -> None:
        for key in [k for k, q in self._failures.items() if not q or q[-1] <= now - self.window]:
            del self._failures[key]
        while len(self._failures) > MAX_TRACKED:  # all recent: forget the oldest keys
            del self._failures[next(iter(self._failures))]


def _name(login: str) -> str:
    return login.strip().lower()


def client_keys(request: Request | WebSocket, login: str) -> list[str]:
    host = request.client.host if request.client else "?"
    return [f"addr:{host}", f"addr+login:{host}:{_name(login)}"]


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
