"""The dashboard inside the web process: two viser servers on 127.0.0.1, reached only through
the login-checking proxy at ``/dashboard`` (:mod:`webui.pages`).

Why two: viser's GUI is shared by every browser on a server, and its ``ClientHandle`` carries
no request, so one server cannot show controls to trainers and hide them from viewers. The
*control* server has the controls; the *view* server has the same live picture with no button
that acts. The proxy picks the upstream by the account's role, so a viewer's browser never
even receives the controls. Both are fed by one :class:`webui.feed.Feed`; a server with no
browser connected costs nothing per tick.

viser runs its own asyncio loop in a thread per server. The share-link tunnel (which any
client can request with a message, button or not) is disabled server-side.
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import logging
import threading
from typing import Any

import viser

from server.runtime import Runtime
from sessions.codes import RANK
from webui.bridge import Bridge
from webui.context import Context
from webui.feed import Feed
from webui.views import View

log = logging.getLogger("ergoseek.dashboard")

HOST = "127.0.0.1"


def _no_share_url(*_: Any, **__: Any) -> None:
    """Replaces ``ViserServer.request_share_url``: no tunnel to viser's share service, ever."""
    log.warning("a dashboard client asked for a public share link: refused")


def viser_server() -> viser.ViserServer:
    """A viser server on a free local port, quiet, with the share tunnel disabled."""
    with contextlib.redirect_stdout(io.StringIO()):  # viser prints its URL table on start
        server = viser.ViserServer(host=HOST, port=0, verbose=False)
    server.request_share_url = _no_share_url  # type: ignore[method-assign]
    return server


class Dashboard:
    def __init__(self, runtime: Runtime, loop: asyncio.AbstractEventLoop) -> None:
        self.runtime = runtime
        self.loop = loop
        self.bridge = Bridge(runtime, loop)
        self.ctx = Context(runtime, self.bridge)
        self.servers: dict[str, viser.ViserServer] = {}
        self.views: dict[str, View] = {}
        self.feed: Feed | None = None
        self._stopped = False
        self._lock = threading.Lock()

    def build(self) -> None:
        """Start the viser servers and build their GUIs (blocking: run it in a thread)."""
        ctx = self.ctx
        ctx.load_users()
        for name, control in (("control", True), ("view", False)):
            server = viser_server()
            self.servers[name] = server
            view = View(server, ctx, control=control)
            self.views[name] = view
            ctx.views.append(view)
        store = self.runtime.store

        def evaluations(session_id: int) -> list[dict[str, Any]]:
            return [
                {"candidate": e.candidate, "power": e.power, "session_t": e.t}
                for e in store.sessions.evaluations(session_id)
            ]

        self.feed = Feed(
            self.runtime.hub,
            self.runtime.machine,
            ctx.views,
            load_evaluations=evaluations,
            on_finished=ctx.session_finished,
        )
        for view in ctx.views:
            ctx.background(view.history.load_user)
            if view.control:
                ctx.background(view.live._show_optimum)
        log.info(
            "dashboard: viser on %s:%d (trainers) and :%d (viewers), reached through /dashboard",
            HOST,
            self.servers["control"].get_port(),
            self.servers["view"].get_port(),
        )

    def upstream(self, role: str) -> str:
        """The viser server an account of this role is proxied to."""
        name = "control" if RANK.get(role, -1) >= RANK["trainer"] else "view"
        return f"ws://{HOST}:{self.servers[name].get_port()}"

    def stop(self) -> None:
        """Stop feeding, then both viser servers. Blocking (call from a thread), idempotent."""
        with self._lock:
            if self._stopped:
                return
            self._stopped = True
        if self.feed is not None:
            self.feed.stop(self.loop)
        self.ctx.close()
        for server in self.servers.values():
            with contextlib.suppress(Exception):
                server.stop()


async def start_dashboard(runtime: Runtime) -> Dashboard:
    """Called from the web process's lifespan; ``runtime.dashboard.stop()`` undoes it."""
    dashboard = Dashboard(runtime, asyncio.get_running_loop())
    try:
        await asyncio.to_thread(dashboard.build)
    except BaseException:
        await asyncio.to_thread(dashboard.stop)
        raise
    assert dashboard.feed is not None
    dashboard.feed.start()
    return dashboard
