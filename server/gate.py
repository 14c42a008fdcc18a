"""The e-stop gate: a small process of its own that owns the server's listening socket, so
that ``POST /api/v1/machine/estop`` reaches the worker whatever the web process is busy with.

    client ──► gate (accept, peek at the request line)
                 ├─ an e-stop: parse its head, check Host, login, role, Origin (as the API does)
                 │            ──► the worker's e-stop line (the ring's header) ──► zero torque
                 └─ anything else: the connection itself (SCM_RIGHTS) ──► the web process

The gate reads nothing but an e-stop: for any other connection it only *peeks* at the first
bytes (``MSG_PEEK``, nothing consumed) and hands the socket to the web process, which serves
it as if it had accepted it. So no body, no parse, no slow client and no busy event loop of
the web process stands between an e-stop request and the worker. An e-stop is authenticated
exactly like the route: a bearer token or the login cookie (the cookie only with one of our
Origins), a trainer or an admin, one of our Host names; refused, it is answered 401/403/400
by the gate, and nothing is stopped. The gate runs at a raised priority when the system
allows it (``estop_gate_nice``).

What crosses between the processes is plain: the socket pair carries connections (one
``C`` per file descriptor) web-ward, and the worker's ring name (``R<name>``, ``R`` for none)
and ``Q`` (quit) gate-ward.
"""

from __future__ import annotations

import asyncio
import contextlib
import http.cookies
import json
import logging
import os
import socket
import sys
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import httptools

log = logging.getLogger("ergoseek.gate")

ESTOP_PATH = b"/api/v1/machine/estop"
ESTOP_LINE = b"POST " + ESTOP_PATH
PEEK_BYTES = len(ESTOP_LINE) + 1
PEEK_WAIT_S = 2.0  # s a connection may take to show its request line (then: handed over)
HEAD_MAX = 16 * 1024  # bytes of an e-stop's head at most
BODY_MAX = 4096
HEAD_WAIT_S = 2.0
MAX_PEEKING = 1024  # connections being peeked at once; past it, handed over unpeeked
COOKIE = "ergoseek_session"  # (server.security.COOKIE; not imported: the gate stays small)
ROLES_ALLOWED = frozenset({"trainer", "admin"})
PROCESS_NAME = "ergoseek-gate"


@dataclass(frozen=True)
class GateConfig:
    """What the gate needs, as plain data."""

    database_url: str
    host_names: tuple[str, ...]
    allowed_origins: tuple[str, ...] = ()
    nice: int = 0


@dataclass
class _Head:
    url: bytes = b""
    headers: dict[str, str] = field(default_factory=dict)
    complete: bool = False

    def on_url(self, url: bytes) -> None:
        self.url += url

    def on_header(self, name: bytes, value: bytes) -> None:
        self.headers[name.decode("latin-1").lower()] = value.decode("latin-1")

    def on_headers_complete(self) -> None:
        self.complete = True


def peeked_kind(data: bytes) -> str:
    """``estop``, ``more`` (a prefix of the e-stop's request line) or ``other``."""
    if data.startswith(ESTOP_LINE) and data[len(ESTOP_LINE) : len(ESTOP_LINE) + 1] in (b" ", b"?"):
        return "estop"
    return "more" if ESTOP_LINE.startswith(data) else "other"


def host_allowed(host_header: str, names: tuple[str, ...]) -> bool:
    """The Host header's name (no port) is one of ``names`` (``*``, ``*.domain`` patterns as
    Starlette's TrustedHostMiddleware takes them)."""
    host = host_header.strip().lower()
    if host.startswith("["):
        host = host[: host.find("]") + 1]
    else:
        host = host.rsplit(":", 1)[0] if host.count(":") == 1 else host
    for pattern in names:
        p = pattern.lower()
        if p in ("*", host) or (p.startswith("*.") and host.endswith(p[1:])):
            return True
    return False


def _reply(status: int, reason: str, body: dict[str, Any]) -> bytes:
    payload = json.dumps(body).encode()
    head = (
        f"HTTP/1.1 {status} {reason}\r\ncontent-type: application/json\r\n"
        f"content-length: {len(payload)}\r\nconnection: close\r\n"
        "x-content-type-options: nosniff\r\nx-frame-options: DENY\r\n"
        "content-security-policy: default-src 'none'; frame-ancestors 'none'\r\n"
    )
    if status == 401:
        head += "www-authenticate: Bearer\r\n"
    return head.encode() + b"\r\n" + payload


class Gate:
    def __init__(self, listener: socket.socket, link: socket.socket, cfg: GateConfig) -> None:
        # The login tokens only (not the whole Store: no Alembic, recorder or password checks to
        # import); the web process migrated the database before it started the gate.
        from sessions.store.database import Database, database_url
        from sessions.store.tokens import TokenRepository, digest

        self.listener = listener
        self.link = link
        self.cfg = cfg
        self.db = Database(database_url(cfg.database_url))
        self.tokens = TokenRepository(self.db)
        self.digest = digest
        self.line: Any = None  # EStopLine of the current worker's ring
        # the live logins (digest → account, expiry), so an e-stop needs no store query; the
        # web process says when logins change ("A<account id>": that account's are dropped
        # at once, then all are read again)
        self.logins: dict[str, tuple[Any, datetime]] = {}
        self._reloading: asyncio.Task[None] | None = None
        self.peeking = 0
        self.tasks: set[asyncio.Future[None]] = set()
        self.done = asyncio.Event()

    # -- the web process's side ---------------------------------------------------------------
    def _on_link(self) -> None:
        try:
            msg = self.link.recv(4096)
        except BlockingIOError:
            return
        except OSError:
            msg = b""
        if not msg or msg == b"Q":  # the web process is gone or asks us to go
            self.done.set()
            return
        if msg.startswith(b"R"):
            self._attach(msg[1:].decode())
        elif msg.startswith(b"A"):
            with contextlib.suppress(ValueError):
                gone = int(msg[1:])
                self.logins = {d: v for d, v in self.logins.items() if v[0].id != gone}
            self._reload()

    def _reload(self) -> None:
        """Read the live logins again (once at a time; a change meanwhile reads again)."""

        async def read() -> None:
            loop = asyncio.get_running_loop()
            try:
                rows = await loop.run_in_executor(None, self.tokens.live)
            except Exception as exc:  # the store is busy or gone: the fallback query remains
                log.warning("reading the logins: %s", exc)
                return
            self.logins = {d: (account, expires) for d, account, expires in rows}

        previous = self._reloading

        async def after() -> None:
            if previous is not None:
                with contextlib.suppress(Exception):
                    await previous
            await read()

        self._reloading = asyncio.ensure_future(after())

    async def _account(self, token: str) -> Any:
        """The account of a live login: from the copy, else from the store (and kept)."""
        key = self.digest(token)
        known = self.logins.get(key)
        if known is not None and known[1] > datetime.now(UTC):
            return known[0]
        loop = asyncio.get_running_loop()
        account = await loop.run_in_executor(None, self.tokens.resolve, token)
        return account

    def _attach(self, name: str) -> None:
        from sessions.worker.ring import EStopLine

        if self.line is not None and self.line.name == name:
            return
        if self.line is not None:
            self.line.close()
            self.line = None
        if name:
            try:
                self.line = EStopLine(name)
            except (OSError, ValueError) as exc:
                log.warning("cannot reach the worker's e-stop line %s: %s", name, exc)

    async def _hand_over(self, conn: socket.socket) -> None:
        """The connection to the web process, untouched (what was peeked is still unread)."""
        try:
            for _ in range(200):  # the web process reads these at once; a full pipe waits
                try:
                    socket.send_fds(self.link, [b"C"], [conn.fileno()])
                    return
                except BlockingIOError:
                    await asyncio.sleep(0.005)
        except OSError:
            self.done.set()
        finally:
            conn.close()

    # -- clients ------------------------------------------------------------------------------
    def _on_accept(self) -> None:
        for _ in range(64):
            try:
                conn, _ = self.listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:  # EMFILE and the like: try again at the next readiness
                log.warning("accept: %s", exc)
                return
            conn.setblocking(False)
            work = self._hand_over(conn) if self.peeking >= MAX_PEEKING else self._sort(conn)
            task = asyncio.ensure_future(work)
            self.tasks.add(task)
            task.add_done_callback(self.tasks.discard)

    async def _readable(self, conn: socket.socket, timeout: float) -> bool:
        loop = asyncio.get_running_loop()
        ready = loop.create_future()
        loop.add_reader(conn.fileno(), lambda: ready.done() or ready.set_result(True))
        try:
            await asyncio.wait_for(ready, timeout)
            return True
        except TimeoutError:
            return False
        finally:
            loop.remove_reader(conn.fileno())

    async def _sort(self, conn: socket.socket) -> None:
        """Peek until the request line tells an e-stop from anything else."""
        self.peeking += 1
        try:
            loop = asyncio.get_running_loop()
            deadline = loop.time() + PEEK_WAIT_S
            while True:
                left = deadline - loop.time()
                if left <= 0 or not await self._readable(conn, left):
                    break  # slow to speak: the web server's own timeouts deal with it
                try:
                    data = conn.recv(PEEK_BYTES, socket.MSG_PEEK)
                except BlockingIOError:
                    continue
                except OSError:
                    conn.close()
                    return
                if not data:
                    conn.close()
                    return
                kind = peeked_kind(data)
                if kind == "estop":
                    await self._estop(conn)
                    return
                if kind == "other":
                    break
                await asyncio.sleep(0.001)  # a prefix of the e-stop line: wait for the rest
        finally:
            self.peeking -= 1
        await self._hand_over(conn)

    async def _estop(self, conn: socket.socket) -> None:
        loop = asyncio.get_running_loop()
        try:
            head = await asyncio.wait_for(self._read_head(conn), HEAD_WAIT_S)
            status, reason, body = (
                (400, "Bad Request", {"detail": "incomplete request"})
                if head is None
                else await self._decide(conn, head)
            )
            with contextlib.suppress(OSError):
                await loop.sock_sendall(conn, _reply(status, reason, body))
        except (TimeoutError, OSError):
            pass
        finally:
            conn.close()

    async def _read_head(self, conn: socket.socket) -> _Head | None:
        loop = asyncio.get_running_loop()
        head = _Head()
        parser = httptools.HttpRequestParser(head)
        seen = 0
        while not head.complete:
            data = await loop.sock_recv(conn, 4096)
            if not data:
                return None
            seen += len(data)
            if seen > HEAD_MAX + BODY_MAX:
                return None
            try:
                parser.feed_data(data)
            except httptools.HttpParserUpgrade:
                return None
            except httptools.HttpParserError:
                return None
        return head

    async def _decide(self, conn: socket.socket, head: _Head) -> tuple[int, str, dict[str, Any]]:
        """The API's answer to this e-stop (and the e-stop itself, if it is allowed)."""
        h = head.headers
        if not host_allowed(h.get("host", ""), self.cfg.host_names):
            return 400, "Bad Request", {"detail": "Invalid host header"}
        if int(h.get("content-length", "0") or 0) > BODY_MAX:
            return 413, "Content Too Large", {"detail": f"request body over {BODY_MAX} bytes"}
        token, how = self._credentials(h)
        if token is None:
            return 401, "Unauthorized", {"detail": "not logged in"}
        account = await self._account(token)
        if account is None:
            return 401, "Unauthorized", {"detail": "login expired or revoked"}
        if how == "cookie" and not self._own_origin(h):
            return 403, "Forbidden", {"detail": "cross-site request refused"}
        if account.role not in ROLES_ALLOWED:
            return 403, "Forbidden", {"detail": f"needs the trainer role (you are {account.role})"}
        if self.line is None:
            return 409, "Conflict", {"detail": "the machine's worker is lost: reset it"}
        self.line.trigger()
        peer = "?"
        with contextlib.suppress(OSError):
            peer = str(conn.getpeername()[0])
        log.info("e-stop by %s from %s", account.login, peer)
        return 202, "Accepted", {"status": "estopped"}

    def _credentials(self, h: dict[str, str]) -> tuple[str | None, str]:
        scheme, _, token = h.get("authorization", "").partition(" ")
        if scheme.lower() == "bearer" and token.strip():
            return token.strip(), "bearer"
        jar = http.cookies.SimpleCookie()
        with contextlib.suppress(http.cookies.CookieError):
            jar.load(h.get("cookie", ""))
        morsel = jar.get(COOKIE)
        return (morsel.value, "cookie") if morsel is not None and morsel.value else (None, "none")

    def _own_origin(self, h: dict[str, str]) -> bool:
        origin, host = h.get("origin"), h.get("host", "")
        own = {f"http://{host}", f"https://{host}", *self.cfg.allowed_origins}
        return origin is not None and origin in own

    # -- life ---------------------------------------------------------------------------------
    async def run(self) -> None:
        loop = asyncio.get_running_loop()
        self.listener.setblocking(False)
        self.link.setblocking(False)
        loop.add_reader(self.link.fileno(), self._on_link)
        loop.add_reader(self.listener.fileno(), self._on_accept)
        self._reload()
        await self.done.wait()
        loop.remove_reader(self.listener.fileno())
        self.listener.close()
        if self.line is not None:
            self.line.close()
        self.db.dispose()


def gate_main(listener: socket.socket, link: socket.socket, cfg: GateConfig) -> None:
    """Entry point of the gate process."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the web process decides when we go
    with contextlib.suppress(OSError):  # a name ps and the tests can tell from the worker's
        Path("/proc/self/comm").write_text(PROCESS_NAME)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    if cfg.nice:
        with contextlib.suppress(OSError):  # refused without the privilege: stay as we are
            os.setpriority(os.PRIO_PROCESS, 0, cfg.nice)
    try:
        import uvloop

        runner = uvloop.run
    except ImportError:  # pragma: no cover
        runner = asyncio.run
    try:
        runner(Gate(listener, link, cfg).run())
    except KeyboardInterrupt:  # pragma: no cover
        sys.exit(0)


class GateLink:
    """The web process's end: starts the gate on the listening socket, takes the connections
    it hands over, tells it the worker's ring."""

    def __init__(self, listener: socket.socket, cfg: GateConfig) -> None:
        import multiprocessing as mp

        self.listener = listener
        self.mine, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        ctx = mp.get_context("spawn")
        self.proc = ctx.Process(
            target=gate_main, args=(listener, theirs, cfg), name="ergoseek-estop-gate", daemon=True
        )
        self.proc.start()
        theirs.close()
        self.mine.setblocking(False)
        self._ring: str | None = None
        self.tasks: set[asyncio.Task[Any]] = set()
        self.closing = False
        self.fallback: asyncio.Server | None = None

    def serve(self, loop: asyncio.AbstractEventLoop, protocol: Any) -> None:
        """From now on, every connection the gate hands over is served by ``protocol()``."""

        def take() -> None:
            while True:
                try:
                    _, fds, _, _ = socket.recv_fds(self.mine, 16, 64)
                except (BlockingIOError, InterruptedError):
                    return
                except OSError:
                    fds = []
                if not fds:  # the gate is gone: accept on the socket ourselves
                    loop.remove_reader(self.mine.fileno())
                    self._fallback(loop, protocol)
                    return
                for fd in fds:
                    conn = socket.socket(fileno=fd)
                    task = loop.create_task(loop.connect_accepted_socket(protocol, conn))
                    self.tasks.add(task)
                    task.add_done_callback(self.tasks.discard)

        loop.add_reader(self.mine.fileno(), take)

    def _fallback(self, loop: asyncio.AbstractEventLoop, protocol: Any) -> None:
        """Without a gate the server still listens (e-stops then go through the API route)."""
        if self.closing:
            return
        log.error("the e-stop gate exited: the web server accepts connections itself")

        async def listen() -> None:
            self.fallback = await loop.create_server(protocol, sock=self.listener)

        task = loop.create_task(listen())
        self.tasks.add(task)
        task.add_done_callback(self.tasks.discard)

    def logins_changed(self, account_id: int) -> None:
        """Logins of ``account_id`` changed (issued, revoked, role, disabled, deleted): the
        gate drops its copy of them at once and reads them again."""
        with contextlib.suppress(OSError):
            self.mine.send(b"A%d" % account_id)

    def ring(self, name: str | None) -> None:
        """The worker's ring, whose e-stop line the gate pulls (None: no worker)."""
        if name != self._ring:
            with contextlib.suppress(OSError):
                self.mine.send(b"R" + (name or "").encode())
                self._ring = name

    def close(self, timeout: float = 2.0) -> None:
        self.closing = True
        if self.fallback is not None:
            self.fallback.close()
        with contextlib.suppress(OSError):
            self.mine.send(b"Q")
        self.proc.join(timeout)
        if self.proc.is_alive():
            self.proc.terminate()
            self.proc.join(1.0)
        self.mine.close()
        self.listener.close()
