"""``/dashboard`` WebSocket: checks the login and the Origin, then relays to the dashboard's
viser server (a Unix socket that needs this process's secret: :mod:`webui.upstream`), telling
it who the account is (:meth:`webui.bridge.Bridge.upstream_headers`).

- Refused before accept (HTTP 403 to the handshake) without a valid login (cookie or bearer
  token), with a cookie but no Origin, from another Origin, without viser's ``viser-v…``
  subprotocol, or past :data:`MAX_CONNECTIONS` in all or :data:`MAX_PER_ACCOUNT` for one
  account.
- The browser's subprotocol is echoed on accept and passed upstream (without it Chromium
  retries forever and viser rejects the version); upstream ``max_size`` is 64 MiB (the
  ``websockets`` default of 1 MiB kills the link on viser's first big message) and
  ``compression=None``. viser → browser frames (binary: zstd msgpack + raw arrays) are
  relayed untouched; browser → viser frames only if they are what a browser sends
  (:func:`webui.frames.admit`: its camera, a value update) and no faster than
  :data:`FRAME_RATE` a second (bursts to :data:`FRAME_BURST`): anything else is dropped and
  counted (logged once per connection).
- An account demoted, disabled or deleted loses its open dashboards at once: the dashboard's
  watch re-reads the accounts every second, or as soon as it is told
  (:meth:`webui.dashboard.Dashboard.changed`), and :meth:`Connections.accounts_now` closes
  (1008) every connection whose account is no longer as it was; the page reconnects and gets
  what the account may see now. The login itself (logout, expiry, revocation) is checked
  again every :data:`RECHECK_S`.
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
from collections import Counter
from dataclasses import dataclass, field

from fastapi import WebSocket, status
from starlette.websockets import WebSocketDisconnect
from websockets.asyncio.client import ClientConnection, unix_connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake

from server.runtime import Runtime
from server.security import COOKIE, bearer, identify, origin_allowed
from sessions.store import AccountRecord, Store
from webui.frames import admit

log = logging.getLogger("ergoseek.dashboard")

MAX_SIZE = 64 * 2**20  # bytes, per message from viser
MAX_CONNECTIONS = 32  # open dashboards in all
MAX_PER_ACCOUNT = 8  # … and of one account (a trainer's tabs and devices)
RECHECK_S = 5.0  # s between checks of the login itself (logout, expiry)
OPEN_TIMEOUT = 5.0
SEND_TIMEOUT_S = 10.0  # a browser that takes longer to accept one frame is dropped
SUBPROTOCOL_PREFIX = "viser-v"
UPSTREAM_URI = "ws://localhost/dashboard"  # (on the Unix socket: only its path matters)
FRAME_RATE, FRAME_BURST = 200.0, 400.0  # frames/s a browser may send (orbiting: ≤ 60/s)


@dataclass(eq=False)
class Connection:
    """One open dashboard socket: whose, and how it ends."""

    account: AccountRecord
    ended: asyncio.Event = field(default_factory=asyncio.Event)
    refused: Counter[str] = field(default_factory=Counter)
    tokens: float = FRAME_BURST
    refilled: float = 0.0

    def spend(self, now: float) -> bool:
        """A token bucket: whether one more frame may pass now."""
        self.tokens = min(FRAME_BURST, self.tokens + (now - self.refilled) * FRAME_RATE)
        self.refilled = now
        if self.tokens < 1.0:
            return False
        self.tokens -= 1.0
        return True

    def still(self, now: AccountRecord | None) -> bool:
        """Whether the account is still as it was when this connection was let in."""
        return now is not None and not now.disabled and now.role == self.account.role


class Connections:
    """The open dashboard sockets (on the web loop only)."""

    def __init__(self) -> None:
        self._open: set[Connection] = set()

    @property
    def open(self) -> int:
        return len(self._open)

    def of(self, account_id: int) -> int:
        return sum(1 for c in self._open if c.account.id == account_id)

    def add(self, conn: Connection) -> None:
        self._open.add(conn)

    def remove(self, conn: Connection) -> None:
        self._open.discard(conn)

    def accounts_now(self, accounts: dict[int, AccountRecord]) -> None:
        """End every connection whose account was demoted, disabled or deleted."""
        for conn in list(self._open):
            if not conn.still(accounts.get(conn.account.id)):
                log.info("dashboard socket of %s closed: its account changed", conn.account.login)
                conn.ended.set()


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
    connections = dashboard.connections
    if connections.open >= MAX_CONNECTIONS:
        await refuse(ws, "too many dashboards open")
        return
    if connections.of(account.id) >= MAX_PER_ACCOUNT:
        await refuse(ws, f"too many dashboards open for {account.login}")
        return
    secret = bearer(ws) or ws.cookies.get(COOKIE) or ""
    try:
        upstream = await unix_connect(
            dashboard.socket_path,
            uri=UPSTREAM_URI,
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
    conn = Connection(account)
    connections.add(conn)
    try:
        await ws.accept(subprotocol=upstream.subprotocol or proto)
        await relay(ws, upstream, runtime.store, secret, conn)
    finally:
        connections.remove(conn)
        with contextlib.suppress(Exception):
            await upstream.close()
        if conn.refused:
            log.warning(
                "dashboard socket of %s: %d frames refused %s",
                account.login,
                conn.refused.total(),
                dict(conn.refused),
            )


async def relay(
    ws: WebSocket, upstream: ClientConnection, store: Store, secret: str, conn: Connection
) -> None:
    """Relay both ways until either side closes or the login ends; then close the other."""
    account = conn.account
    tasks = {
        asyncio.create_task(_browser_to_viser(ws, upstream, conn), name="dashboard-in"),
        asyncio.create_task(_viser_to_browser(ws, upstream, account), name="dashboard-out"),
        asyncio.create_task(_recheck(store, secret, account), name="dashboard-login"),
        asyncio.create_task(_ended(conn), name="dashboard-account"),
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


async def _browser_to_viser(
    ws: WebSocket, upstream: ClientConnection, conn: Connection
) -> tuple[int, str]:
    loop = asyncio.get_running_loop()
    conn.refilled = loop.time()
    while True:
        msg = await ws.receive()
        if msg["type"] == "websocket.disconnect":
            return (1000, "")
        data = msg.get("bytes")
        if data is None:
            data = msg.get("text")
        why = admit(data)
        if why is None and not conn.spend(loop.time()):
            why = f"more than {FRAME_RATE:.0f} frames/s"
        if why is None:
            await upstream.send(data)  # type: ignore[arg-type]
            continue
        if not conn.refused:
            log.warning("dashboard socket of %s: frame refused (%s)", conn.account.login, why)
        conn.refused[why] += 1


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


async def _ended(conn: Connection) -> tuple[int, str]:
    """Until the account changes (:meth:`Connections.accounts_now`)."""
    await conn.ended.wait()
    return (status.WS_1008_POLICY_VIOLATION, "account changed")


def _closable(code: int) -> int:
    """A close code a server may send (1005/1006/1015 are reserved for 'none received')."""
    allowed = code in (1000, 1001, 1002, 1003, 1007, 1008, 1009, 1010, 1011)
    return code if allowed or 3000 <= code < 5000 else 1011
