"""``/dashboard`` WebSocket: checks the login and the Origin, then relays to the local viser
server for the account's role.

- Refused before accept (HTTP 403 to the handshake) without a valid login (cookie or bearer
  token), with a cookie but no Origin, from another Origin, without viser's ``viser-v…``
  subprotocol, or past :data:`MAX_CONNECTIONS`.
- The browser's subprotocol is echoed on accept and passed upstream (without it Chromium
  retries forever and viser rejects the version); upstream ``max_size`` is 64 MiB (the
  ``websockets`` default of 1 MiB kills the link on viser's first big message) and
  ``compression=None``. Frames (binary: zstd msgpack + raw arrays) are relayed untouched.
- The login is checked again every :data:`RECHECK_S`: a logout, an expired or revoked token,
  a disabled account or a role change closes the connection (1008).
- Either side closing closes the other; the upstream connection is always closed.
- A browser that stops reading (one frame not taken in :data:`SEND_TIMEOUT_S`) is closed:
  viser keeps every frame for a slow client, so this bounds what a stuck tab costs; the
  client reconnects and gets the current state. Other browsers and the web process's loop
  never wait for it either way (each connection relays on its own).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging

from fastapi import WebSocket, status
from starlette.websockets import WebSocketDisconnect
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake

from server.runtime import Runtime
from server.security import COOKIE, bearer, identify, origin_allowed
from sessions.store import AccountRecord, Store

log = logging.getLogger("ergoseek.dashboard")

MAX_SIZE = 64 * 2**20  # bytes, per message from viser
MAX_CONNECTIONS = 32
RECHECK_S = 15.0
OPEN_TIMEOUT = 5.0
SEND_TIMEOUT_S = 10.0  # a browser that takes longer to accept one frame is dropped
SUBPROTOCOL_PREFIX = "viser-v"


class _Count:
    open = 0


_count = _Count()


def pick_subprotocol(ws: WebSocket) -> str | None:
    offered = ws.scope.get("subprotocols") or []
    return next((p for p in offered if p.startswith(SUBPROTOCOL_PREFIX)), None)


async def refuse(ws: WebSocket, why: str) -> None:
    log.info("dashboard socket refused (%s) from %s", why, ws.client.host if ws.client else "?")
    await ws.close(code=status.WS_1008_POLICY_VIOLATION)


async def dashboard_socket(ws: WebSocket, runtime: Runtime) -> None:
    dashboard = runtime.dashboard
    if dashboard is None:
        await refuse(ws, "no dashboard")
        return
    account, how = await asyncio.to_thread(identify, ws, runtime.store)
    if account is None:
        await refuse(ws, "not logged in")
        return
    if how == "cookie" and ws.headers.get("origin") is None:
        await refuse(ws, "cookie without Origin")
        return
    if not origin_allowed(ws, runtime.settings.allowed_origins):
        await refuse(ws, f"Origin {ws.headers.get('origin')!r}")
        return
    proto = pick_subprotocol(ws)
    if proto is None:
        await refuse(ws, "no viser subprotocol")
        return
    if _count.open >= MAX_CONNECTIONS:
        await refuse(ws, "too many dashboards open")
        return
    secret = bearer(ws) or ws.cookies.get(COOKIE) or ""
    try:
        upstream = await connect(
            dashboard.upstream(account.role),
            subprotocols=[proto],  # type: ignore[list-item]
            additional_headers=dashboard.bridge.upstream_headers(account),
            max_size=MAX_SIZE,
            compression=None,
            open_timeout=OPEN_TIMEOUT,
            ping_interval=None,
            close_timeout=2.0,
        )
    except (OSError, InvalidHandshake, TimeoutError) as exc:
        log.error("dashboard: viser did not accept the proxy (%s)", exc)
        await ws.close(code=status.WS_1011_INTERNAL_ERROR)
        return
    _count.open += 1
    try:
        await ws.accept(subprotocol=upstream.subprotocol or proto)
        await relay(ws, upstream, runtime.store, secret, account)
    finally:
        _count.open -= 1
        with contextlib.suppress(Exception):
            await upstream.close()


async def relay(
    ws: WebSocket, upstream: ClientConnection, store: Store, secret: str, account: AccountRecord
) -> None:
    """Relay both ways until either side closes or the login ends; then close the other."""
    tasks = {
        asyncio.create_task(_browser_to_viser(ws, upstream), name="dashboard-in"),
        asyncio.create_task(_viser_to_browser(ws, upstream, account), name="dashboard-out"),
        asyncio.create_task(_recheck(store, secret, account), name="dashboard-login"),
    }
    code, reason, browser_gone = 1000, "", False
    try:
        done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        for task in done:
            exc = task.exception()
            if exc is None:
                code, reason = task.result()
                browser_gone = browser_gone or task.get_name() == "dashboard-in"
            elif isinstance(exc, ConnectionClosed):  # viser closed or dropped the link
                code = exc.rcvd.code if exc.rcvd is not None else status.WS_1011_INTERNAL_ERROR
                reason = exc.rcvd.reason if exc.rcvd is not None else ""
            else:  # sending to or receiving from the browser failed: it is gone
                browser_gone = True
                if not isinstance(exc, WebSocketDisconnect | RuntimeError | OSError):
                    log.error("dashboard relay: %r", exc)
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        with contextlib.suppress(Exception):
            await upstream.close()
        if not browser_gone:
            with contextlib.suppress(Exception):
                async with asyncio.timeout(2.0):
                    await ws.close(code=_closable(code), reason=reason[:120])


async def _browser_to_viser(ws: WebSocket, upstream: ClientConnection) -> tuple[int, str]:
    while True:
        msg = await ws.receive()
        if msg["type"] == "websocket.disconnect":
            return (1000, "")
        data = msg.get("bytes")
        if data is None:
            data = msg.get("text")
        if data is not None:
            await upstream.send(data)


async def _viser_to_browser(
    ws: WebSocket, upstream: ClientConnection, account: AccountRecord
) -> tuple[int, str]:
    async for data in upstream:
        try:
            async with asyncio.timeout(SEND_TIMEOUT_S):
                if isinstance(data, bytes):
                    await ws.send_bytes(data)
                else:
                    await ws.send_text(data)
        except TimeoutError:
            log.warning("dashboard socket of %s closed: the browser stopped reading", account.login)
            return (status.WS_1008_POLICY_VIOLATION, "too slow")
    return (upstream.close_code or 1000, upstream.close_reason or "")


async def _recheck(store: Store, secret: str, account: AccountRecord) -> tuple[int, str]:
    """Every RECHECK_S: the login still valid, the same account with the same role."""
    while True:
        await asyncio.sleep(RECHECK_S)
        now = await asyncio.to_thread(store.tokens.resolve, secret)
        if now is None or now.disabled or now.role != account.role or now.id != account.id:
            log.info("dashboard socket of %s closed: login ended or changed", account.login)
            return (status.WS_1008_POLICY_VIOLATION, "login ended")


def _closable(code: int) -> int:
    """A close code a server may send (1005/1006/1015 are reserved for 'none received')."""
    allowed = code in (1000, 1001, 1002, 1003, 1007, 1008, 1009, 1010, 1011)
    return code if allowed or 3000 <= code < 5000 else 1011
