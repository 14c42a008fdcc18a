"""The emulated ODrive on a pseudo-terminal: the host opens the pty's slave path like any
serial device; the emulator serves the master end, in raw mode (``tty.setraw``) so no line
discipline rewrites bytes.

Lines end on ``\\r``, ``\\n`` or ``!``; over 256 characters without an end, the line is
dropped (:class:`LineReader`, as the firmware's stream parser). Each line goes to the device's
interpreter (:mod:`.ascii`) after its physics is brought up to the moment the line arrived.

Fault injection (:meth:`OdriveEmulator.inject`) makes the line misbehave the way real ones do:
garbage, short replies, partial lines, silence, unsolicited lines, bad checksums;
:meth:`OdriveEmulator.device_fault` makes the drive fail (motor, encoder, e-stop, DC bus,
overspeed), into its error registers as its firmware does.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import time
import tty
from multiprocessing.connection import Connection
from typing import Literal

from sessions.machine.odrive.emulator.ascii import AsciiProtocol, frame
from sessions.machine.odrive.emulator.device import (
    Device,
    DeviceFault,
    EmulatorConfig,
    EmulatorSnapshot,
)
from sessions.machine.odrive.protocol import MAX_LINE

Injection = Literal["garbage", "short", "partial", "silence", "extra", "bad-checksum"]
INJECTIONS: tuple[str, ...] = ("garbage", "short", "partial", "silence", "extra", "bad-checksum")
LINE_END = (0x0D, 0x0A, 0x21)  # \r \n !


class LineReader:
    """Bytes in, whole lines out; a line longer than :data:`MAX_LINE` is dropped to its end.
    ``pending``: a partial line already in the buffer (left by a host that died mid-line)."""

    def __init__(self, pending: bytes = b"") -> None:
        self.rx = bytearray(pending[:MAX_LINE])
        self.read_active = True

    def feed(self, data: bytes) -> list[bytes]:
        lines = []
        rx = self.rx
        for b in data:
            if b in LINE_END:
                if self.read_active:
                    lines.append(bytes(rx))
                rx.clear()
                self.read_active = True
            else:
                if len(rx) >= MAX_LINE:
                    rx.clear()
                    self.read_active = False
                if self.read_active:
                    rx.append(b)
        return lines


class LineFaults:
    """The injected misbehaviour of the line: which, and for how many more lines."""

    def __init__(self) -> None:
        self.pending: tuple[str, int | None] | None = None

    def set(self, kind: Injection | None, count: int | None) -> None:
        if kind is not None and kind not in INJECTIONS:
            raise ValueError(f"unknown injection {kind!r}; one of {', '.join(INJECTIONS)}")
        self.pending = None if kind is None else (kind, count)

    def take(self) -> str | None:
        if self.pending is None:
            return None
        kind, count = self.pending
        if count is None:
            return kind
        count -= 1
        self.pending = (kind, count) if count > 0 else None
        return kind

    def give_back(self, kind: str) -> None:
        if self.pending is None:
            self.pending = (kind, 1)
        elif self.pending[1] is not None:
            self.pending = (kind, self.pending[1] + 1)

    @staticmethod
    def corrupt(kind: str, replies: list[bytes], use_ck: bool) -> bytes:
        """What goes on the wire instead of ``replies``."""
        if kind == "garbage":
            return b"\x8f\x00#%&\xfe\xa5" + os.urandom(3).replace(b"\n", b"x") + b"\r\n"
        if kind == "short":
            return frame(replies[0].split(b" ")[0][:3], use_ck)
        if kind == "partial":
            return frame(replies[0], use_ck)[:-4]
        if kind == "bad-checksum":
            return b"".join(frame(r, True, bad_ck=True) for r in replies)
        if kind == "extra":
            out = b"".join(frame(r, use_ck) for r in replies)
            return out + frame(b"0.000000 0.000000", use_ck)
        return b""


class OdriveEmulator:
    """Serve one emulated ODrive on a new pty. ``start()`` runs it in a thread (tests, tools);
    ``serve_forever()`` runs it in the calling thread (``ergoseek emulate-odrive``)."""

    def __init__(self, rig: EmulatorConfig | None = None) -> None:
        self.device = Device(rig)
        self.rig = self.device.rig
        self.protocol = AsciiProtocol(self.device)
        self.lines_in = LineReader(self.rig.partial_line.encode("ascii"))
        self.faults = LineFaults()
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        self.lock = threading.RLock()
        self._wake_r, self._wake_w = os.pipe()
        self._thread: threading.Thread | None = None
        self._running = False

    @property
    def log(self) -> list[tuple[float, str]]:
        return list(self.device.log)

    @property
    def log_total(self) -> int:
        return self.device.log_total

    # -- the line ------------------------------------------------------------------------------
    def _handle(self, line: bytes, now: float) -> bytes:
        faults = self.faults
        inj = faults.take()
        if inj == "silence":
            return b""
        replies = self.protocol.process_line(line, now)
        use_ck = self.protocol.use_ck
        if inj is None or (not replies and inj != "extra"):
            if inj is not None and inj != "extra":
                faults.give_back(inj)  # nothing to corrupt: keep it for the next reply
            return b"".join(frame(r, use_ck) for r in replies)
        return faults.corrupt(inj, replies, use_ck)

    def _receive(self, data: bytes, now: float) -> None:
        out = bytearray()
        for line in self.lines_in.feed(data):
            out += self._handle(line, now)
        if out:
            with contextlib.suppress(BlockingIOError, OSError):
                os.write(self.master, out)  # a full line buffer drops bytes, like a UART

    # -- running -----------------------------------------------------------------------------
    def poll_once(self, timeout: float, control: Connection | None = None) -> None:
        fds = (
            (self.master, self._wake_r)
            if control is None
            else (self.master, self._wake_r, control.fileno())
        )
        ready, _, _ = select.select(fds, (), (), timeout)
        now = time.monotonic()
        with self.lock:
            self.device.catch_up(now)
            if self.master in ready:
                try:
                    data = os.read(self.master, 4096)
                except OSError:  # EAGAIN, or EIO on systems where no slave is open
                    data = b""
                if data:
                    self._receive(data, now)
        if self._wake_r in ready:
            with contextlib.suppress(BlockingIOError):
                os.read(self._wake_r, 64)
        if control is not None and len(ready) > 0 and control.fileno() in ready:
            self._serve_control(control)

    def serve_forever(self, control: Connection | None = None) -> None:
        """Serve until :meth:`stop` (or, with a control pipe, its ``close`` request or EOF)."""
        self._running = True
        while self._running:
            self.poll_once(0.002, control)

    def _serve_control(self, control: Connection) -> None:
        try:
            name, args = control.recv()
        except (EOFError, OSError):
            self._running = False
            return
        if name == "close":
            self._running = False
            control.send(None)
            return
        try:
            result = getattr(self, name)(*args)
        except Exception as exc:
            result = exc
        control.send(result)

    def start(self) -> OdriveEmulator:
        if self._thread is None:
            self._running = True
            self._thread = threading.Thread(
                target=self.serve_forever, name="odrive-emulator", daemon=True
            )
            self._thread.start()
        return self

    def stop(self) -> None:
        self._running = False
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def close(self) -> None:
        self.stop()
        for fd in (self.master, self.slave, self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> OdriveEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- observation and fault injection -----------------------------------------------------
    def inject(self, kind: Injection | None, count: int | None = 1) -> None:
        """Misbehave on the next ``count`` lines (None: until cleared with ``inject(None)``):
        garbage bytes, a short reply, a reply without its line end, silence (lines neither
        processed nor answered: the watchdog starves too), an unsolicited extra line, a wrong
        reply checksum."""
        with self.lock:
            self.faults.set(kind, count)

    def device_fault(self, kind: DeviceFault) -> None:
        """The drive fails now: ``motor``, ``encoder``, ``estop``, ``undervoltage``,
        ``overspeed`` (its registers set as the firmware sets them, the axis idle)."""
        now = time.monotonic()
        with self.lock:
            self.device.catch_up(now)
            self.device.fault(kind, now)

    def snapshot(self) -> EmulatorSnapshot:
        now = time.monotonic()
        with self.lock:
            return self.device.snapshot(now)

    def torques_since(self, t: float) -> list[tuple[float, float]]:
        """``c`` setpoints (arrival time, motor N·m) received after monotonic time t."""
        with self.lock:
            return self.device.torque_log.since(t)

    def events(self) -> list[tuple[float, str]]:
        with self.lock:
            return list(self.device.log)
