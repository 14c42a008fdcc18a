"""How the dashboard's GUI code, which runs on viser's threads, reaches the web process, and
who each browser is.

viser runs its own asyncio loop in a daemon thread and calls plain (non-async) GUI callbacks
on its thread pool. Nothing here ever blocks viser's loop: callbacks that act are plain
functions (so they run on viser's pool), and they hand the action to the web process's event
loop, where :class:`server.service.MachineService` lives (it is not thread-safe: its worker
pipe and session state belong to that loop). Store calls run on the calling pool thread.

Who: viser's ``ClientHandle`` carries no request, so the proxy (:mod:`webui.proxy`) adds
headers to its upstream connection — the per-process secret (which the upstream's handshake
gate, :mod:`webui.upstream`, already required), the account id, its login and its role.
:meth:`Bridge.identify` reads them once, when the browser's own GUI is built; that GUI is the
browser's alone (``client.gui``), so a click on it is that account's. Actions other than the
E-STOP check the account in the store again (still enabled, still a trainer).
"""

from __future__ import annotations

import asyncio
import hmac
import logging
import secrets
from collections.abc import Callable, Coroutine
from dataclasses import dataclass
from typing import Any, TypeVar

import viser

from server.runtime import Runtime
from server.service import MachineService
from sessions.codes import RANK
from sessions.store import AccountRecord, NotFoundError, Store
from webui.upstream import PROXY_HEADER

log = logging.getLogger("ergoseek.dashboard")

ACCOUNT_HEADER = "x-ergoseek-account"
LOGIN_HEADER = "x-ergoseek-login"
ROLE_HEADER = "x-ergoseek-role"
ACTION_TIMEOUT = 20.0  # s: a start waits for the worker (up to 10 s) and the store

T = TypeVar("T")


@dataclass(frozen=True)
class Who:
    """The account behind one browser's dashboard, as the proxy vouched for it."""

    account_id: int
    login: str
    role: str

    @property
    def trainer(self) -> bool:
        """Trainers and admins get the controls; viewers do not."""
        return RANK.get(self.role, -1) >= RANK["trainer"]


class Bridge:
    def __init__(self, runtime: Runtime, loop: asyncio.AbstractEventLoop) -> None:
        self.runtime = runtime
        self.loop = loop
        self.secret = secrets.token_urlsafe(32)

    @property
    def store(self) -> Store:
        return self.runtime.store

    @property
    def machine(self) -> MachineService:
        """The machine service: call it on the web process's loop (:meth:`run`, :meth:`call`,
        :meth:`soon`), never from a GUI thread directly."""
        return self.runtime.machine

    # -- crossing to the web process's loop ---
    def run(self, coro: Coroutine[Any, Any, T], timeout: float = ACTION_TIMEOUT) -> T:
        """Run a coroutine on the web process's loop and wait for it (from a thread only)."""
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def call(self, fn: Callable[..., T], *args: Any, timeout: float = ACTION_TIMEOUT) -> T:
        """Call a plain function on the web process's loop and wait for it (from a thread)."""

        async def on_loop() -> T:
            return fn(*args)

        return self.run(on_loop(), timeout)

    def soon(self, fn: Callable[..., Any], *args: Any) -> None:
        """Schedule a plain function on the web process's loop; never waits."""
        self.loop.call_soon_threadsafe(fn, *args)

    # -- who is asking ---
    def upstream_headers(self, account: AccountRecord) -> dict[str, str]:
        return {
            PROXY_HEADER: self.secret,
            ACCOUNT_HEADER: str(account.id),
            LOGIN_HEADER: account.login,
            ROLE_HEADER: account.role,
        }

    def identify(self, server: viser.ViserServer, client_id: int) -> Who | None:
        """The account the proxy vouched for on this viser connection (no I/O); None if the
        connection did not come through the proxy or viser's internals changed."""
        try:
            conn = server._websock_server._live_connections.get(client_id)  # type: ignore[attr-defined]
            headers = conn.request.headers if conn is not None else None
        except AttributeError:  # a viser without these internals: nobody is trusted
            log.error("viser internals changed: dashboards get no controls")
            return None
        if headers is None or not hmac.compare_digest(headers.get(PROXY_HEADER, ""), self.secret):
            return None
        try:
            account_id = int(headers.get(ACCOUNT_HEADER, ""))
        except ValueError:
            return None
        role = headers.get(ROLE_HEADER, "")
        if role not in RANK:
            return None
        return Who(account_id, headers.get(LOGIN_HEADER, "?"), role)

    def trainer(self, who: Who) -> AccountRecord | None:
        """The account if it may act now (trainer or admin, enabled); store I/O: call it
        from a thread."""
        try:
            account = self.store.accounts.get(who.account_id)
        except NotFoundError:
            return None
        if account.disabled or RANK[account.role] < RANK["trainer"]:
            return None
        return account
