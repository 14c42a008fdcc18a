"""Raw HTTP over a socket, for what a well-behaved client never sends: a 50 MB body, a body
announced but never sent, chunked bodies without end, bytes that are not HTTP at all. Used by
the body-limit tests and the e-stop benchmark's flood (loopback only, always bounded)."""

from __future__ import annotations

import contextlib
import select
import socket
import time
from dataclasses import dataclass

MB = 1 << 20


@dataclass(frozen=True)
class RawReply:
    status: int | None  # None: the server closed without a status line
    head: bytes  # the status line and headers as received
    seconds: float  # from the first byte sent to the status line (or the close)
    sent: int  # body bytes the server took before it answered or closed


def _status(head: bytes) -> int | None:
    line = head.split(b"\r\n", 1)[0].split()
    return int(line[1]) if len(line) >= 2 and line[1].isdigit() else None


def request_head(method: str, path: str, host: str, headers: dict[str, str]) -> bytes:
    lines = [
        f"{method} {path} HTTP/1.1",
        f"Host: {host}",
        *(f"{k}: {v}" for k, v in headers.items()),
    ]
    return ("\r\n".join(lines) + "\r\n\r\n").encode()


def raw_request(
    port: int,
    head: bytes,
    body: bytes | None = None,
    *,
    body_size: int = 0,
    chunked: bool = False,
    timeout: float = 10.0,
    piece: int = 256 * 1024,
) -> RawReply:
    """Send ``head``, then ``body`` (or ``body_size`` zero bytes, plain or chunked) while
    watching for the server's answer; stop sending as soon as one arrives or the server
    closes. ``body_size`` bytes are never held in memory at once."""
    t0 = time.monotonic()
    sent = 0
    got = b""
    total = len(body) if body is not None else body_size
    zeros = bytes(piece)
    out = b""  # framed bytes not yet taken by the socket
    queued = 0  # body bytes framed so far
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as s:
        s.sendall(head)
        deadline = t0 + timeout
        while time.monotonic() < deadline:
            if not out and queued < total:
                n = min(piece, total - queued)
                chunk = body[queued : queued + n] if body is not None else zeros[:n]
                out = f"{n:x}\r\n".encode() + chunk + b"\r\n" if chunked else chunk
                queued += n
            readable, writable, _ = select.select([s], [s] if out else [], [], 0.05)
            if readable:
                try:
                    data = s.recv(65536)
                except OSError:
                    break
                if not data:
                    break
                got += data
                if b"\r\n\r\n" in got:
                    break
            elif writable:
                try:
                    k = s.send(out[:65536])
                except OSError:  # the server closed (reset) on us: its answer may be in
                    got += _left_to_read(s)  # our receive buffer still (as curl reads it)
                    break
                out = out[k:]
                sent += k
    return RawReply(_status(got), got.split(b"\r\n\r\n", 1)[0], time.monotonic() - t0, sent)


def _left_to_read(s: socket.socket) -> bytes:
    """What had arrived before a reset: Linux keeps received bytes readable after an RST
    (a server that answers and closes with our body unread resets the connection, and
    the send that finds it fails before the answer was read)."""
    got = b""
    s.settimeout(0.0)
    with contextlib.suppress(OSError):
        while data := s.recv(65536):
            got += data
    return got


def garbage(port: int, payload: bytes, timeout: float = 2.0) -> int | None:
    """Bytes that are not HTTP; the status the server answers with (None if it just closes)."""
    with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout) as s:
        s.sendall(payload)
        with contextlib.suppress(OSError):
            return _status(s.recv(4096))
    return None


# -- a bounded flood, for the e-stop benchmark ------------------------------------------------
GARBAGE: tuple[bytes, ...] = (
    b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03" + bytes(64),  # a TLS hello on plain HTTP
    b"\xff\xfe\x00 not http at all\r\n\r\n",
    b"GET /" + b"A" * 8000 + b" HTTP/1.1\r\nHost: x\r\n\r\n",
    b"POST /api/v1/auth/login HTTP/1.1\r\nHost: {host}\r\nContent-Length: 9\r\n\r\n{not json",
    b"POST /api/v1/auth/token HTTP/1.1\r\nHost: {host}\r\nContent-Type: application/json\r\n"
    b"Content-Length: 38\r\n\r\n" + b'{"login":"trainer","password":"wrong"}',
    b'POST /api/v1/users HTTP/1.1\r\nHost: {host}\r\nContent-Length: 11\r\n\r\n{"name":1}]',
    b"GET /api/v1/machine HTTP/1.1\r\nHost: {host}\r\nAuthorization: Bearer forged\r\n\r\n",
    b"POST /api/v1/machine/estop HTTP/1.1\r\nHost: evil.example\r\nContent-Length: 0\r\n\r\n",
    b"GET /../../etc/passwd HTTP/1.1\r\nHost: {host}\r\n\r\n",
)


def flood(port: int, seconds: float, rate: float, bodies_per_s: float, body_mb: int) -> dict:
    """For ``seconds``: ``rate`` requests a second of :data:`GARBAGE` (one connection each),
    and, from a second thread, ``body_mb`` MB bodies (announced, then chunked) at most
    ``bodies_per_s`` a second. Bounded in time and count; loopback only. What it got back."""
    import threading
    from collections import Counter

    host = f"127.0.0.1:{port}".encode()
    end = time.monotonic() + seconds
    codes: Counter[str] = Counter()
    lock = threading.Lock()

    def note(code: int | None) -> None:
        with lock:
            codes[str(code)] += 1

    def bodies() -> None:
        n = 0
        while time.monotonic() < end and n < bodies_per_s * seconds:
            chunked = bool(n % 2)
            how = (
                {"Transfer-Encoding": "chunked"}
                if chunked
                else {"Content-Length": str(body_mb * MB)}
            )
            head = request_head(
                "POST", "/api/v1/users", host.decode(), {"Content-Type": "application/json", **how}
            )
            r = raw_request(port, head, body_size=body_mb * MB, chunked=chunked, timeout=5)
            note(r.status)
            n += 1
            time.sleep(1.0 / bodies_per_s)

    streamer = threading.Thread(target=bodies, daemon=True)
    streamer.start()
    sent = 0
    t_next = time.monotonic()
    while time.monotonic() < end and sent < rate * seconds:
        payload = GARBAGE[sent % len(GARBAGE)].replace(b"{host}", host)
        note(garbage(port, payload, timeout=2.0))
        sent += 1
        t_next += 1.0 / rate
        time.sleep(max(0.0, t_next - time.monotonic()))
    streamer.join(10)
    return {"garbage_sent": sent, "codes": dict(codes)}
