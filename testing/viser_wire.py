"""A raw viser 1.1 WebSocket client, no browser: what an attacker on the same machine (or a
logged-in account with a script instead of a browser) can send and receive.

    server → client: [u64 LE msgpack size][u64 LE zstd size][zstd(msgpack {"messages": …})]…
    client → server: one plain msgpack map per binary frame, {"type": <Message class>, …}

(viser's ``WebsocketClientWorker.ts`` and ``infra/_infra.py``.) A viser connection gets its
per-client GUI only after its first ``ViewerCameraMessage``, so :meth:`RawClient.hello` sends
one, as a browser does 50 ms after it mounts.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec
import viser
import zstandard
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect, unix_connect

SUBPROTOCOL = f"viser-v{viser.__version__}"
_zstd = zstandard.ZstdDecompressor()

CAMERA: dict[str, Any] = {
    "type": "ViewerCameraMessage",
    "wxyz": [1.0, 0.0, 0.0, 0.0],
    "position": [1.2, -1.6, 0.55],
    "fov": 1.0,
    "near": 0.01,
    "far": 100.0,
    "image_height": 950,
    "image_width": 1500,
    "look_at": [0.1, 0.0, 0.05],
    "up_direction": [0.0, 0.0, 1.0],
}


def decode(frame: bytes) -> list[dict[str, Any]]:
    """The messages of one server → client frame."""
    raw_n = int.from_bytes(frame[0:8], "little")
    comp_n = int.from_bytes(frame[8:16], "little")
    inner = _zstd.decompress(frame[16 : 16 + comp_n], max_output_size=raw_n)
    return list(msgspec.msgpack.decode(inner)["messages"])


def encode(message: dict[str, Any]) -> bytes:
    return msgspec.msgpack.encode(message)


def gui_update(uuid: str, **updates: Any) -> bytes:
    """A ``GuiUpdateMessage``: ``value=…`` is what a browser sends (a click on a button is
    ``value=True``); anything else is an attack on viser's handle state."""
    return encode({"type": "GuiUpdateMessage", "uuid": uuid, "updates": updates})


@dataclass
class RawClient:
    """One raw viser connection; every message received is kept in :attr:`messages`."""

    ws: ClientConnection
    messages: list[dict[str, Any]] = field(default_factory=list)
    closed: ConnectionClosed | None = None

    def send(self, frame: bytes) -> None:
        self.ws.send(frame)

    def hello(self) -> None:
        """The first camera message: viser now counts the client connected and builds its
        per-client GUI."""
        self.send(encode(CAMERA))

    def receive(self, seconds: float) -> list[dict[str, Any]]:
        """Messages that arrive within ``seconds`` (fewer if the server closes)."""
        got: list[dict[str, Any]] = []
        end = time.monotonic() + seconds
        while self.closed is None and (left := end - time.monotonic()) > 0:
            try:
                frame = self.ws.recv(timeout=left)
            except TimeoutError:
                break
            except ConnectionClosed as exc:
                self.closed = exc
                break
            if isinstance(frame, bytes):
                got.extend(decode(frame))
        self.messages.extend(got)
        return got

    def wait_for(self, label: str, kind: str | None = None, timeout: float = 20.0) -> str:
        """The uuid of the GUI element labelled ``label`` (of message type ``kind``), once
        it has arrived."""
        end = time.monotonic() + timeout
        while True:
            found = self.find(label, kind)
            if found is not None:
                return found
            if self.closed is not None or time.monotonic() > end:
                raise AssertionError(f"no GUI element {label!r} ({kind}) arrived")
            self.receive(0.2)

    def find(self, label: str, kind: str | None = None) -> str | None:
        for m in self.elements():
            if m["props"].get("label") == label and (kind is None or m["type"] == kind):
                return str(m["uuid"])
        return None

    def elements(self) -> Iterator[dict[str, Any]]:
        """Every GUI element created (a ``Gui…Message`` with props), in arrival order."""
        for m in self.messages:
            if m.get("type", "").startswith("Gui") and isinstance(m.get("props"), dict):
                yield m

    def updates_of(self, uuid: str) -> list[dict[str, Any]]:
        """The property updates received for one element."""
        return [
            m["updates"]
            for m in self.messages
            if m.get("type") == "GuiUpdateMessage" and m.get("uuid") == uuid
        ]

    def close(self) -> None:
        self.ws.close()

    def __enter__(self) -> RawClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# a browser's wire, as viser speaks it: its subprotocol, frames of any size, no compression
_WIRE: dict[str, Any] = {"subprotocols": [SUBPROTOCOL], "max_size": None, "compression": None}


def open_proxy(url: str, headers: dict[str, str], timeout: float = 10.0) -> RawClient:
    """Through the login-checking proxy (``ws://host:port/dashboard``) with a login's
    headers (cookie and Origin, or a bearer token)."""
    ws = connect(
        url,
        additional_headers=headers,
        open_timeout=timeout,
        **_WIRE,
    )
    return RawClient(ws)


def open_unix(path: str, headers: dict[str, str] | None = None, timeout: float = 10.0) -> RawClient:
    """Straight to a viser server on a Unix socket, as a local process would."""
    ws = unix_connect(
        path,
        uri="ws://localhost/",
        additional_headers=headers,
        open_timeout=timeout,
        **_WIRE,
    )
    return RawClient(ws)


def open_tcp(url: str, headers: dict[str, str] | None = None, timeout: float = 10.0) -> RawClient:
    """Straight to a viser server on a TCP port, as a local process would."""
    ws = connect(
        url,
        additional_headers=headers,
        open_timeout=timeout,
        **_WIRE,
    )
    return RawClient(ws)


def tcp_listeners(pid: int) -> set[tuple[str, int]]:
    """(address, port) of every TCP socket the process ``pid`` listens on (from /proc)."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        with contextlib.suppress(OSError):
            target = os.readlink(fd)
            if target.startswith("socket:["):
                inodes.add(target[8:-1])
    found = set()
    for table in ("tcp", "tcp6"):
        path = Path(f"/proc/{pid}/net/{table}")
        if not path.exists():
            continue
        for line in path.read_text().splitlines()[1:]:
            cols = line.split()
            if cols[3] == "0A" and cols[9] in inodes:  # LISTEN
                addr, port = cols[1].rsplit(":", 1)
                found.add((addr, int(port, 16)))
    return found
