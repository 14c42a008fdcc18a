"""The viser server behind the proxy, reachable by the proxy only (issue 12.3).

viser has no authentication, and a raw client receives the shared GUI state before any
callback could object. So the viser server
- listens on a **Unix socket** in a fresh directory only this process's user can enter
  (``0700``): nothing of the dashboard is on TCP, so no other user's process and no other
  machine reaches it; and
- refuses, at the WebSocket **handshake**, any connection that does not present the
  per-process secret the proxy sends (``x-ergoseek-proxy``), with HTTP 403 before viser runs
  any code for it — against processes of the same user, whom the directory does not stop.
  Plain HTTP gets 404: viser's own file server is never used (FastAPI serves the page).

How: viser builds its server with ``websockets.asyncio.server.serve(handler, host, port,
process_request=…, …)`` on its loop thread while ``ViserServer()`` waits for it. For the
length of that constructor only (under a lock), that module attribute is a wrapper that puts
our gate in as ``process_request`` and binds the Unix socket instead of ``host:port``; the
bound server keeps the gate for its life. This relies on public ``websockets`` API and on
viser calling it with a ``process_request`` keyword, nothing private of viser; the tests
connect to the socket without the secret and must be refused.

viser's constructor blocks forever if it cannot bind (it retries "ports" and never signals),
so the path is checked first and the constructor runs on a thread with a deadline.
"""

from __future__ import annotations

import contextlib
import hmac
import http
import io
import logging
import os
import shutil
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import viser
import websockets.asyncio.server as ws_server

log = logging.getLogger("ergoseek.dashboard")

PROXY_HEADER = "x-ergoseek-proxy"
START_TIMEOUT = 20.0  # s for viser to bind its socket
MAX_PATH = 100  # bytes: a Unix socket path (sun_path is 108 on Linux)
_swap = threading.Lock()


def gate(secret: str) -> Callable[[Any, Any], Any]:
    """A ``process_request`` that lets through only WebSocket handshakes with the secret."""

    def process_request(connection: Any, request: Any) -> Any:
        if not hmac.compare_digest(request.headers.get(PROXY_HEADER, ""), secret):
            return connection.respond(http.HTTPStatus.FORBIDDEN, "Forbidden\n")
        if request.headers.get("Upgrade", "").lower() != "websocket":
            return connection.respond(http.HTTPStatus.NOT_FOUND, "Not found\n")
        return None

    return process_request


class Upstream:
    """A private directory, the socket in it and the viser server on it."""

    def __init__(self, secret: str) -> None:
        self.secret = secret
        self.directory = Path(tempfile.mkdtemp(prefix="ergoseek-dashboard-"))  # 0700
        self.path = str(self.directory / "viser.sock")
        if len(os.fsencode(self.path)) > MAX_PATH:
            raise RuntimeError(f"the dashboard's socket path is too long: {self.path}")
        self.server: viser.ViserServer | None = None

    def start(self) -> viser.ViserServer:
        """Construct the viser server on the socket (blocking, with a deadline)."""
        made: list[viser.ViserServer] = []
        failed: list[BaseException] = []

        def construct() -> None:
            try:
                made.append(_gated_server(self.secret, self.path))
            except BaseException as exc:
                failed.append(exc)

        thread = threading.Thread(target=construct, name="ergoseek-viser-start", daemon=True)
        thread.start()
        thread.join(START_TIMEOUT)
        if failed:
            raise RuntimeError(f"the dashboard's viser server did not start: {failed[0]!r}")
        if not made:
            raise RuntimeError(f"the dashboard's viser server did not bind {self.path}")
        self.server = made[0]
        os.chmod(self.path, 0o600)
        log.info("dashboard: viser on %s (proxy only)", self.path)
        return self.server

    def stop(self) -> None:
        if self.server is not None:
            with contextlib.suppress(Exception), contextlib.redirect_stdout(io.StringIO()):
                self.server.stop()
        shutil.rmtree(self.directory, ignore_errors=True)


def _gated_server(secret: str, path: str) -> viser.ViserServer:
    real_serve = ws_server.serve

    def serve(handler: Any, host: Any = None, port: Any = None, **kwargs: Any) -> Any:
        kwargs["process_request"] = gate(secret)  # (viser's own HTTP file server: dropped)
        # Not ws_server.unix_serve: that calls this module attribute, i.e. this wrapper.
        return real_serve(handler, unix=True, path=path, **kwargs)

    with _swap:
        ws_server.serve = serve  # type: ignore[assignment]
        try:
            with contextlib.redirect_stdout(io.StringIO()):  # viser prints its URL table
                return viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
        finally:
            ws_server.serve = real_serve  # type: ignore[assignment]
