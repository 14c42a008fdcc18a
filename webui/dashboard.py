"""The dashboard inside the web process: one viser server that only the login-checking proxy
at ``/dashboard`` can reach (:mod:`webui.upstream`: a Unix socket in a private directory, a
per-process secret at the handshake), one shared picture and a dashboard of its own for each
browser (:mod:`webui.views`).

    browser ─► /dashboard (proxy: login, Origin, message filter) ─► viser (Unix socket, gated)
    viser: SharedView (3D machine, live charts)  +  one ClientView per browser (controls)
    Feed (web loop → feed thread) ─► SharedView once, each ClientView
    Watch (web loop): users and accounts re-read from the store while a dashboard is open

A browser's own dashboard is built from the role the proxy vouched for: a viewer's has no
control at all (the E-STOP, Start, Stop, Reset and the Users tab exist only in a trainer's
or admin's). When an account is demoted or disabled the proxy closes its dashboards at once
(:mod:`webui.proxy`); the page reconnects and gets what the account may see now.

viser runs its own asyncio loop in a thread. The share-link tunnel (which any client can
request with a message, button or not) is disabled server-side, and the proxy never lets
that message through anyway (:mod:`webui.frames`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from typing import Any

import viser

from server.runtime import Runtime
from webui import csp
from webui.bridge import Bridge
from webui.context import Context
from webui.feed import Feed
from webui.proxy import Connections
from webui.upstream import Upstream
from webui.views import ClientView, SharedView

log = logging.getLogger("ergoseek.dashboard")

WATCH_S = 1.0  # s between re-reads of users and accounts while a dashboard is open


def _no_share_url(*_: Any, **__: Any) -> None:
    """Replaces ``ViserServer.request_share_url``: no tunnel to viser's share service, ever."""
    log.warning("a dashboard client asked for a public share link: refused")


class Dashboard:
    def __init__(self, runtime: Runtime, loop: asyncio.AbstractEventLoop) -> None:
        self.runtime = runtime
        self.loop = loop
        self.bridge = Bridge(runtime, loop)
        self.ctx = Context(runtime, self.bridge)
        self.upstream = Upstream(self.bridge.secret)
        self.connections = Connections()
        self.server: viser.ViserServer | None = None
        self.shared: SharedView | None = None
        self.feed: Feed | None = None
        self.watch: asyncio.Task[None] | None = None
        self._poke = asyncio.Event()
        self._stopped = False
        self._lock = threading.Lock()

    @property
    def socket_path(self) -> str:
        """The Unix socket the proxy connects to (nothing else may: it needs the secret)."""
        return self.upstream.path

    def build(self) -> None:
        """Start the viser server and the shared picture (blocking: run it in a thread)."""
        ctx = self.ctx
        ctx.load_users()
        csp.dashboard_policy()  # (the page's hashes, computed once, before the first page)
        server = self.server = self.upstream.start()
        server.request_share_url = _no_share_url  # type: ignore[method-assign]
        self.shared = SharedView(server, ctx)
        server.on_client_connect(self._connected)
        server.on_client_disconnect(self._disconnected)
        store = self.runtime.store

        def evaluations(session_id: int) -> list[dict[str, Any]]:
            return [
                {"candidate": e.candidate, "power": e.power, "session_t": e.t}
                for e in store.sessions.evaluations(session_id)
            ]

        self.feed = Feed(
            self.runtime.hub,
            self.runtime.machine,
            self.shared,
            ctx.views,
            load_evaluations=evaluations,
            on_finished=ctx.session_finished,
        )

    # -- browsers (viser's thread pool) ---
    def _connected(self, client: viser.ClientHandle) -> None:
        started = time.perf_counter()
        assert self.server is not None
        who = self.bridge.identify(self.server, client.client_id)
        if who is None:  # (the gate lets only the proxy in: this is a bug or a viser change)
            log.error("dashboard client %s: not vouched for by the proxy", client.client_id)
            self._drop(client.client_id)
            return
        # The users as the store has them now (the watch skips re-reads while no dashboard is
        # open); if they change while this one is built, a re-read may have missed it.
        self.ctx.load_users()
        options = self.ctx.user_options()
        try:
            view = ClientView(client, who, self.ctx)
        except Exception:  # (a half-built dashboard is worse than none: the page reconnects)
            log.exception("building the dashboard of client %s: closing it", client.client_id)
            self._drop(client.client_id)
            return
        self.ctx.add_view(client.client_id, view)
        if self.ctx.user_options() != options:
            view.users_changed(self.ctx.user_options())
        log.info(
            "dashboard client %s (%s, %s) built in %.0f ms",
            client.client_id,
            who.login,
            who.role,
            1e3 * (time.perf_counter() - started),
        )

    def _drop(self, client_id: int) -> None:
        """Close one viser connection (viser's internals; best effort)."""
        with contextlib.suppress(Exception):
            ws = self.server._websock_server  # type: ignore[union-attr]
            conn = ws._live_connections[client_id]
            asyncio.run_coroutine_threadsafe(conn.close(1011), ws._background_event_loop)

    def _disconnected(self, client: viser.ClientHandle) -> None:
        self.ctx.drop_view(client.client_id)  # (viser drops the client's elements itself)

    # -- users and accounts changed ---
    def changed(self) -> None:
        """Users or accounts changed (thread-safe): re-read them now, not at the next
        :data:`WATCH_S`."""
        with contextlib.suppress(RuntimeError):  # the loop is closed: we are stopping
            self.loop.call_soon_threadsafe(self._poke.set)

    async def _watch(self) -> None:
        """While a dashboard is open: users added or renamed anywhere reach every picker;
        an account demoted, disabled or deleted loses its dashboards at once."""
        store = self.runtime.store
        while True:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._poke.wait(), WATCH_S)
            self._poke.clear()
            if not self.connections.open:
                continue
            try:
                accounts = await asyncio.to_thread(store.accounts.list)
                self.connections.accounts_now({a.id: a for a in accounts})
                await asyncio.to_thread(self.ctx.refresh_users, force=False)
            except Exception:
                log.exception("dashboard: re-reading users and accounts")

    def start(self) -> None:
        """On the web loop: the feed and the watch."""
        assert self.feed is not None
        self.feed.start()
        self.watch = asyncio.get_running_loop().create_task(self._watch(), name="dashboard-watch")

    def stop(self) -> None:
        """Stop feeding, then the viser server. Blocking (call from a thread), idempotent."""
        with self._lock:
            if self._stopped:
                return
            self._stopped = True
        if self.watch is not None:
            with contextlib.suppress(RuntimeError):
                self.loop.call_soon_threadsafe(self.watch.cancel)
        if self.feed is not None:
            self.feed.stop(self.loop)
        self.ctx.close()
        self.upstream.stop()


async def start_dashboard(runtime: Runtime) -> Dashboard:
    """Called from the web process's lifespan; ``runtime.dashboard.stop()`` undoes it."""
    dashboard = Dashboard(runtime, asyncio.get_running_loop())
    try:
        await asyncio.to_thread(dashboard.build)
    except BaseException:
        await asyncio.to_thread(dashboard.stop)
        raise
    dashboard.start()
    return dashboard
