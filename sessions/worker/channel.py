"""The worker's event queue to its parent: a pipe written without ever blocking.

``multiprocessing.Queue`` pickles and writes in a feeder thread, which competes with the
real-time loop for the GIL and can block the worker's exit on a parent that stopped reading.
Here the worker pickles an event when it happens (rare: a few per second) and writes frames
``<u32 length><pickle>`` to a non-blocking pipe; what the pipe cannot take now stays in a
bounded backlog, flushed a little every cycle. If the parent stops reading for long, the oldest
backlog is dropped and counted (``dropped``), never the loop's time.
The parent reads whatever is there, reassembles frames and unpickles: also without blocking.
"""

from __future__ import annotations

import os
import pickle
import struct
from collections import deque
from multiprocessing.connection import Connection
from typing import Any

_LEN = struct.Struct("<I")


class EventSender:
    def __init__(self, conn: Connection, backlog: int = 4096) -> None:
        self.conn = conn  # kept open: it owns the fd
        self.fd = conn.fileno()
        os.set_blocking(self.fd, False)
        self.pending: deque[bytes] = deque()
        self.offset = 0  # bytes of pending[0] already written
        self.backlog = backlog
        self.dropped = 0
        self.broken = False

    def send(self, obj: Any) -> None:
        data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
        self.pending.append(_LEN.pack(len(data)) + data)
        while len(self.pending) > self.backlog:
            if self.offset and len(self.pending) > 1:  # never cut a frame half-written
                first = self.pending.popleft()
                self.pending.popleft()
                self.pending.appendleft(first)
            else:
                self.pending.popleft()
                self.offset = 0
            self.dropped += 1
        self.flush()

    def flush(self) -> None:
        pending = self.pending
        while pending and not self.broken:
            frame = pending[0]
            try:
                n = os.write(self.fd, memoryview(frame)[self.offset :])
            except BlockingIOError:
                return
            except OSError:  # the parent is gone
                self.broken = True
                pending.clear()
                return
            self.offset += n
            if self.offset < len(frame):
                return
            pending.popleft()
            self.offset = 0

    def close(self) -> None:
        self.conn.close()


class EventReceiver:
    def __init__(self, conn: Connection) -> None:
        self.conn = conn
        self.fd = conn.fileno()
        os.set_blocking(self.fd, False)
        self.buf = bytearray()
        self.eof = False

    def receive(self) -> list[Any]:
        """Every complete event available now; never blocks."""
        while not self.eof:
            try:
                chunk = os.read(self.fd, 1 << 16)
            except BlockingIOError:
                break
            except OSError:
                self.eof = True
                break
            if not chunk:
                self.eof = True
                break
            self.buf += chunk
        out = []
        buf = self.buf
        while len(buf) >= 4:
            (n,) = _LEN.unpack_from(buf)
            if len(buf) < 4 + n:
                break
            out.append(pickle.loads(bytes(buf[4 : 4 + n])))
            del buf[: 4 + n]
        return out

    def close(self) -> None:
        self.conn.close()
