"""Full-rate telemetry in shared memory: one writer (the worker), any number of readers in any
process, and nobody ever waits for anybody.

Layout of the block (POSIX shared memory, native byte order, sections 64-byte aligned)::

    header  int64[16]   MAGIC, VERSION, capacity, width, head, heartbeat_ns, state, session,
                        pid, cycles, …
    seq     int64[capacity]            sequence number of the record held by each slot
    data    float64[capacity, width]   the records; columns: :data:`COLUMNS`

``head`` counts the records ever written; record n lives in slot ``n % capacity``. The writer
stores the record, then its ``seq``, then ``head = n + 1``: plain stores, no lock, no wait.
A reader keeps a cursor (the next n it wants). To read it snapshots ``head``, copies the slots
from its cursor up, then reads ``head`` again: a record the writer may have started to
overwrite meanwhile (``n <= head_after - capacity``) is dropped, and every record between the
cursor and the first one returned counts as *missed*, exactly; the copied ``seq`` values are
checked too. So a reader that keeps up sees every sample in order, and one that falls behind
learns how many it lost. (Stores are ordered on x86-64, where this runs; the seq check guards
against a torn record elsewhere.)

The header also carries the worker's heartbeat (monotonic ns, written every cycle and every
idle poll), its state code and session number: the parent's liveness check reads them here.
And one word goes the other way: ``H_ESTOP``, an e-stop request any process holding the ring's
name may stamp (:class:`EStopLine`); the worker looks at it every period and latches on a new
stamp, whatever its command pipe holds.

The parent creates the block (:meth:`TelemetryRing.create`, registered with multiprocessing's
resource tracker so it is removed even if the parent is killed) and unlinks it; the worker and
readers attach by name without registering, so no reader's exit can remove it.
"""

from __future__ import annotations

import _posixshmem  # the module multiprocessing.shared_memory itself uses
import contextlib
import mmap
import os
import time
from dataclasses import dataclass
from multiprocessing import shared_memory

import numpy as np

from sessions.telemetry import RECORD_INDEX, RECORD_NAMES, RECORD_UNITS, RECORD_WIDTH

MAGIC = 0x3147_4E49_5245_4B45  # "EKERING1"
VERSION = 1
HEADER_WORDS = 16
H_MAGIC, H_VERSION, H_CAPACITY, H_WIDTH, H_HEAD, H_HEARTBEAT = 0, 1, 2, 3, 4, 5
H_STATE, H_SESSION, H_PID, H_CYCLES = 6, 7, 8, 9
H_ESTOP = 10  # the newest e-stop request: a monotonic-ns stamp any process may write

# A record's columns are the telemetry's (sessions.telemetry); the worker state codes in the
# header and the bits of the flags column are sessions.codes'.
COLUMNS: tuple[str, ...] = RECORD_NAMES
COLUMN_UNITS: dict[str, str] = RECORD_UNITS
INDEX: dict[str, int] = RECORD_INDEX
WIDTH = RECORD_WIDTH


def _layout(capacity: int, width: int) -> tuple[int, int, int]:
    """(seq offset, data offset, total size) in bytes."""
    seq_off = HEADER_WORDS * 8
    data_off = seq_off + ((capacity * 8 + 63) // 64) * 64
    return seq_off, data_off, data_off + capacity * width * 8


def _attach(name: str, writable: bool) -> mmap.mmap:
    """Map an existing block without telling the resource tracker (which would remove the
    block when this process exits)."""
    fd = _posixshmem.shm_open("/" + name, os.O_RDWR if writable else os.O_RDONLY, mode=0o600)
    try:
        size = os.fstat(fd).st_size
        prot = mmap.PROT_READ | (mmap.PROT_WRITE if writable else 0)
        return mmap.mmap(fd, size, mmap.MAP_SHARED, prot)
    finally:
        os.close(fd)


class _View:
    """numpy views of a mapped ring."""

    def __init__(self, buf: mmap.mmap | memoryview, *, writable: bool) -> None:
        hdr = np.ndarray((HEADER_WORDS,), dtype=np.int64, buffer=buf)
        if int(hdr[H_MAGIC]) != MAGIC or int(hdr[H_VERSION]) != VERSION:
            raise ValueError("not an ergoseek telemetry ring (or another version)")
        self.capacity = int(hdr[H_CAPACITY])
        self.width = int(hdr[H_WIDTH])
        seq_off, data_off, _ = _layout(self.capacity, self.width)
        self.hdr = hdr
        self.seq = np.ndarray((self.capacity,), dtype=np.int64, buffer=buf, offset=seq_off)
        self.data = np.ndarray(
            (self.capacity, self.width), dtype=np.float64, buffer=buf, offset=data_off
        )
        if not writable:
            for a in (self.hdr, self.seq, self.data):
                a.flags.writeable = False

    def release(self) -> None:
        del self.hdr, self.seq, self.data


@dataclass(frozen=True)
class RingInfo:
    """What a process needs to open a reader: plain data, picklable."""

    name: str
    capacity: int
    columns: tuple[str, ...] = COLUMNS


class TelemetryRing:
    """The parent's side: creates and finally removes the block; reads the header."""

    def __init__(self, shm: shared_memory.SharedMemory) -> None:
        self.shm = shm
        self.view = _View(shm.buf, writable=True)

    @classmethod
    def create(cls, capacity: int = 1 << 15, width: int = WIDTH) -> TelemetryRing:
        if capacity < 16:
            raise ValueError("ring capacity must be at least 16 records")
        size = _layout(capacity, width)[2]
        shm = shared_memory.SharedMemory(create=True, size=size)
        hdr = np.ndarray((HEADER_WORDS,), dtype=np.int64, buffer=shm.buf)
        hdr[:] = 0
        hdr[H_CAPACITY] = capacity
        hdr[H_WIDTH] = width
        hdr[H_VERSION] = VERSION
        hdr[H_MAGIC] = MAGIC
        del hdr
        ring = cls(shm)
        ring.view.seq[:] = -1
        return ring

    @property
    def name(self) -> str:
        return self.shm.name

    @property
    def info(self) -> RingInfo:
        return RingInfo(self.name, self.view.capacity)

    def header(self, index: int) -> int:
        return int(self.view.hdr[index])

    def close(self) -> None:
        """Unmap and remove the block (readers keep their mappings)."""
        self.view.release()
        try:
            self.shm.close()
        finally:
            with contextlib.suppress(FileNotFoundError):
                self.shm.unlink()


def stamp_estop(hdr: np.ndarray) -> None:
    """Ask for an e-stop through a writable header (one aligned 8-byte store: atomic)."""
    hdr[H_ESTOP] = time.monotonic_ns()


class EStopLine:
    """Another process's line to the worker's e-stop: the ring's header, mapped writable,
    used for nothing but :meth:`trigger`."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.mm = _attach(name, writable=True)
        self.hdr = np.ndarray((HEADER_WORDS,), dtype=np.int64, buffer=self.mm)
        if int(self.hdr[H_MAGIC]) != MAGIC:
            raise ValueError("not an ergoseek telemetry ring")

    def trigger(self) -> None:
        stamp_estop(self.hdr)

    def close(self) -> None:
        del self.hdr
        self.mm.close()


class RingWriter:
    """The worker's side. ``write`` never blocks, never allocates beyond the row it is given."""

    __slots__ = ("mm", "view", "hdr", "seq", "data", "capacity", "head")

    def __init__(self, name: str) -> None:
        self.mm = _attach(name, writable=True)
        self.view = _View(self.mm, writable=True)
        self.hdr = self.view.hdr
        self.seq = self.view.seq
        self.data = self.view.data
        self.capacity = self.view.capacity
        self.head = int(self.hdr[H_HEAD])

    def write(self, row: tuple[float, ...]) -> int:
        """Append one record (``WIDTH`` floats); returns its sequence number."""
        n = self.head
        slot = n % self.capacity
        self.data[slot] = row
        self.seq[slot] = n
        self.head = n + 1
        self.hdr[H_HEAD] = n + 1
        return n

    def beat(self, state: int) -> None:
        hdr = self.hdr
        hdr[H_HEARTBEAT] = time.monotonic_ns()
        hdr[H_STATE] = state

    def set(self, index: int, value: int) -> None:
        self.hdr[index] = value

    def close(self) -> None:
        self.view.release()
        del self.hdr, self.seq, self.data
        self.mm.close()


@dataclass(frozen=True)
class RingBatch:
    """Records ``seq[0] …`` in order (``seq`` ascending, no gaps inside a batch), and how many
    were lost before the first of them since the previous read."""

    seq: np.ndarray  # int64 (n,)
    data: np.ndarray  # float64 (n, WIDTH)
    missed: int

    def __len__(self) -> int:
        return len(self.seq)

    def column(self, name: str) -> np.ndarray:
        return self.data[:, INDEX[name]]


class RingReader:
    """Reads a ring from any process, without ever making the writer wait.

    ``start``: "now" (only records written from now on), "oldest" (everything still held), or
    a sequence number. Read-only mapping: a reader cannot disturb the worker.
    """

    def __init__(self, info: RingInfo | str, start: str | int = "now") -> None:
        name = info.name if isinstance(info, RingInfo) else info
        self.name = name
        self.mm = _attach(name, writable=False)
        self.view = _View(self.mm, writable=False)
        self.capacity = self.view.capacity
        head = int(self.view.hdr[H_HEAD])
        if start == "now":
            self.cursor = head
        elif start == "oldest":
            self.cursor = max(0, head - self.capacity + 1)
        elif isinstance(start, int) and start >= 0:
            self.cursor = start
        else:
            raise ValueError(f"start must be 'now', 'oldest' or a sequence number, not {start!r}")
        self.missed_total = 0

    @property
    def head(self) -> int:
        return int(self.view.hdr[H_HEAD])

    def heartbeat_age(self) -> float:
        """Seconds since the writer's last heartbeat (inf before the first)."""
        hb = int(self.view.hdr[H_HEARTBEAT])
        return (time.monotonic_ns() - hb) * 1e-9 if hb else float("inf")

    def header(self, index: int) -> int:
        return int(self.view.hdr[index])

    def read(self, max_records: int | None = None) -> RingBatch:
        """Everything new since the last read (at most ``max_records``, the oldest first).
        Never blocks."""
        cap = self.capacity
        head = int(self.view.hdr[H_HEAD])
        cursor = self.cursor
        if cursor > head:  # a reader started at a future sequence number waits for it
            return RingBatch(np.zeros(0, np.int64), np.zeros((0, self.view.width)), 0)
        lo = max(cursor, head - cap + 1)
        hi = head
        if max_records is not None and hi - lo > max_records:
            hi = lo + max_records
        n = hi - lo
        if n > 0:
            slots = np.arange(lo, hi) % cap
            a, b = lo % cap, lo % cap + n
            if b <= cap:
                data = self.view.data[a:b].copy()
                seq = self.view.seq[a:b].copy()
            else:
                data = self.view.data[slots]
                seq = self.view.seq[slots]
        else:
            data = np.zeros((0, self.view.width))
            seq = np.zeros(0, np.int64)
        after = int(self.view.hdr[H_HEAD])
        first_valid = max(lo, after - cap + 1)
        if n > 0:
            expected = np.arange(lo, hi, dtype=np.int64)
            bad = np.flatnonzero(seq != expected)
            if len(bad):  # torn: everything up to the last bad record is lost
                first_valid = max(first_valid, lo + int(bad[-1]) + 1)
            k = max(0, min(first_valid, hi) - lo)
            if k:
                data, seq = data[k:], seq[k:]
        missed = max(0, min(first_valid, hi) - cursor) if n > 0 else max(0, lo - cursor)
        self.cursor = hi if n > 0 else max(cursor, lo)
        self.missed_total += missed
        return RingBatch(seq, data, missed)

    def close(self) -> None:
        self.view.release()
        with contextlib.suppress(BufferError):  # batches are copies; nothing should be left
            self.mm.close()

    def __enter__(self) -> RingReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
