"""How the dashboard's GUI code, which runs on viser's threads, reaches the web process.

viser runs its own asyncio loop in a daemon thread and calls plain (non-async) GUI callbacks
on its thread pool. Nothing here ever blocks viser's loop: callbacks that act are plain
functions (so they run on viser's pool), and they hand the action to the web process's event
loop, where :class:`server.service.MachineService` lives (it is not thread-safe: its worker
pipe and session state belong to that loop). Store calls run on the calling pool thread.

Who clicked: viser's ``ClientHandle`` carries no request, so the proxy (``webui.proxy``) adds
two headers to its upstream connection: a per-process secret and the account id. A callback
that acts looks the clicking connection up and checks both; a connection that did not come
through the proxy (e.g. a local process talking to viser's port directly) can watch but never
act.
"""

from __future__ import annotations

import asyncio
import hmac
import logging
import secrets
from collections.abc import Callable, Coroutine
from typing import Any, TypeVar

import viser

from server.runtime import Runtime
from server.service import MachineService
from sessions.codes import RANK
from sessions.store import AccountRecord, NotFoundError, Store

log = logging.getLogger("ergoseek.dashboard")

PROXY_HEADER = "x-ergoseek-proxy"
ACCOUNT_HEADER = "x-ergoseek-account"
ACTION_TIMEOUT = 20.0  # s: a start waits for the worker (up to 10 s) and the store

T = TypeVar("T")


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
        return {PROXY_HEADER: self.secret, ACCOUNT_HEADER: str(account.id)}

    def proxied_account_id(self, server: viser.ViserServer, client_id: int | None) -> int | None:
        """The account id the proxy vouched for on this viser connection (no I/O)."""
        if client_id is None:
            return None
        try:
            conn = server._websock_server._live_connections.get(client_id)  # type: ignore[attr-defined]
            headers = conn.request.headers if conn is not None else None
        except AttributeError:  # a viser without these internals: nobody may act
            log.error("viser internals changed: dashboard actions are refused")
            return None
        if headers is None:
            return None
        if not hmac.compare_digest(headers.get(PROXY_HEADER, ""), self.secret):
            return None
        try:
            return int(headers.get(ACCOUNT_HEADER, ""))
        except ValueError:
            return None

    def trainer(self, server: viser.ViserServer, client_id: int | None) -> AccountRecord | None:
        """The clicking account if it may act (trainer or admin, enabled); store I/O: call it
        from a thread."""
        account_id = self.proxied_account_id(server, client_id)
        if account_id is None:
            return None
        try:
            account = self.store.accounts.get(account_id)
        except NotFoundError:
            return None
        if account.disabled or RANK[account.role] < RANK["trainer"]:
            return None
        return account
