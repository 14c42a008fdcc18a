"""The serial line to an ODrive: one request in flight, every reply checked (pyserial).

Framing (:mod:`.protocol`): each line sent ends in ``\\n`` and, with ``use_checksum``, carries
``*CK``; each reply must be one whole ``\\r\\n``-terminated line with a valid checksum, printable
ASCII, nothing after it. Nothing here waits longer than ``timeout`` for a byte. Every failure
is a :class:`MachineError` saying what came (or did not).

Reading values as the firmware prints them (:meth:`AsciiLink.read_float`, ``read_int``,
``read_flags``): ``inf``/``nan`` floats, ``%ud`` integers (``0d``, firmware 0.5.2-0.5.3),
``lu`` for a 64-bit register on the release builds (unreadable), 9-character replies that may
have been cut. Writes have no reply on success: :meth:`AsciiLink.write` follows each with a
read, so that a refusal (``not implemented``, ``invalid property``) is caught and named.

:meth:`AsciiLink.sync` starts a conversation safely when the device may hold a partial line
(a host that died mid-line): ``*999\\n`` ends it as a line whose checksum cannot match, so it
is dropped, never executed; whatever was in flight is drained; a read with a known answer
proves the line is in step.
"""

from __future__ import annotations

import contextlib
import math
import os
import select
import time

import serial

from sessions.machine.base import MachineError
from sessions.machine.odrive.protocol import FLUSH_LINE, MAX_LINE, R_REPLY_MAX, checksum

ERROR_REPLIES = (
    "invalid command format",
    "invalid motor",
    "invalid property",
    "not implemented",
    "unknown command",
)
UNREADABLE_64 = "unreadable: this firmware build prints 64-bit integers as 'lu'"
BEAT_EVERY = 0.02  # s: a long wait calls ``beat`` this often (the worker's heartbeat)


def _nothing() -> None:
    return None


class AsciiLink:
    """One ODrive's serial line. ``uint_suffix``: integers print ``%ud`` (0.5.2-0.5.3)."""

    def __init__(self, device: str, baudrate: int, timeout: float, use_checksum: bool) -> None:
        self.device = device
        self.baudrate = baudrate
        self.timeout = timeout
        self.use_checksum = use_checksum
        self.ser: serial.Serial | None = None
        self.fd = -1
        self.buf = bytearray()
        self.uint_suffix = False
        self.beat = _nothing  # called while a wait lasts (the owner's keepalive)

    # -- the port --------------------------------------------------------------------------------
    def open(self) -> None:
        try:
            self.ser = serial.Serial(
                self.device,
                self.baudrate,
                timeout=0,  # reads and writes never block: the waits are ours (select)
                write_timeout=0,
                exclusive=True,
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise MachineError(f"cannot open {self.device}: {exc}") from None
        self.fd = self.ser.fileno()
        self.flush_input()

    def close(self) -> None:
        ser, self.ser = self.ser, None
        self.fd = -1
        self.buf.clear()
        if ser is not None:
            with contextlib.suppress(Exception):
                ser.close()

    @property
    def is_open(self) -> bool:
        return self.ser is not None and self.ser.is_open

    def flush_input(self) -> None:
        if self.ser is not None:
            self.ser.reset_input_buffer()
        self.buf.clear()

    def drain(self, quiet: float, limit: float) -> bytes:
        """Read and discard until the line has been quiet for ``quiet`` s (at most ``limit``)."""
        got = bytearray(self.buf)
        self.buf.clear()
        ser = self.ser
        if ser is None:
            return bytes(got)
        end = time.monotonic() + limit
        silent_since = time.monotonic()
        while True:
            now = time.monotonic()
            wait = min(quiet - (now - silent_since), end - now, BEAT_EVERY)
            if wait <= 0.0:
                break
            ready, _, _ = select.select((self.fd,), (), (), wait)
            self.beat()
            if not ready:
                continue
            silent_since = time.monotonic()
            chunk = ser.read(4096)
            if not chunk:
                break
            got += chunk
        return bytes(got)

    def sync(self, probe: str) -> str:
        """Start in step whatever the device holds: ``*999\\n`` (a partial line there is
        dropped, never executed), drain, then ``probe`` (a read) must answer."""
        self.flush_input()
        self.send(FLUSH_LINE)
        self.drain(quiet=max(0.005, 2.0 * self.timeout), limit=0.5)
        return self.ask(probe)

    # -- framing -----------------------------------------------------------------------------------
    def encode(self, text: str) -> bytes:
        data = text.encode("ascii")
        if self.use_checksum:
            data += b" "
            data += b"*%d" % checksum(data)
        return data + b"\n"

    def send(self, data: bytes) -> None:
        """Write ``data`` whole, waiting at most ``timeout`` for the line to take it. A write
        times out only if an attempt made after the deadline still could not finish: a process
        descheduled past its deadline (a host stall) finds its bytes gone, not a dead line.
        (pyserial's own write timeout checks its clock after a write that completed.)"""
        if self.ser is None:
            raise MachineError("serial port not open")
        fd = self.fd
        rest = memoryview(data)
        deadline = time.monotonic() + self.timeout
        while True:
            tried = time.monotonic()
            try:
                rest = rest[os.write(fd, rest) :]
            except BlockingIOError:
                pass  # the line's buffer is full: wait for room
            except OSError as exc:
                raise MachineError(f"serial write failed: {exc}") from None
            if not rest:
                return
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                if tried >= deadline:
                    raise MachineError(f"write timed out after {self.timeout * 1e3:.0f} ms")
                continue  # one more attempt, made after the deadline
            try:
                _, ready, _ = select.select((), (fd,), (), min(remaining, BEAT_EVERY))
            except OSError as exc:
                raise MachineError(f"serial write failed: {exc}") from None
            if not ready:
                self.beat()  # a long wait: the heartbeat goes on

    def send_text(self, text: str) -> None:
        self.send(self.encode(text))

    def reply(self, request: bytes) -> str:
        """The one reply line to ``request`` (already sent), checked; nothing else may follow."""
        return self.check(self.line(request), request)

    def line(self, request: bytes, alone: bool = True) -> bytes:
        """Wait (at most ``timeout``) for the reply's line; return it without its ``\\n``.
        ``alone``: nothing may follow it (else the rest stays for the next line)."""
        buf = self.buf
        deadline = time.monotonic() + self.timeout
        ser = self.ser
        assert ser is not None
        while True:
            i = buf.find(b"\n")
            if i >= 0:
                break
            if len(buf) > MAX_LINE:
                raise MachineError(f"garbled reply to {show(request)}: {show(bytes(buf[:40]))}…")
            remaining = deadline - time.monotonic()
            if remaining <= 0.0 and not self._take_available(buf):
                what = f"partial line {show(bytes(buf))}" if buf else "no reply"
                raise MachineError(
                    f"timeout: {what} to {show(request)} within {self.timeout * 1e3:.0f} ms"
                )
            if remaining <= 0.0:
                continue  # the last look found bytes: parse them
            try:
                ready, _, _ = select.select((self.fd,), (), (), min(remaining, BEAT_EVERY))
                if not ready:
                    self.beat()  # a long wait: the heartbeat goes on
                else:
                    chunk = ser.read(4096)
                    if chunk:
                        buf += chunk
            except (serial.SerialException, OSError) as exc:
                raise MachineError(f"serial read failed: {exc}") from None
        line = bytes(buf[:i])
        del buf[: i + 1]
        if buf and alone:
            extra = bytes(buf)
            buf.clear()
            raise MachineError(f"unexpected data after the reply to {show(request)}: {show(extra)}")
        return line

    def check(self, line: bytes, request: bytes, errors_ok: bool = False) -> str:
        """A reply line's text: framing, checksum, encoding checked; an error reply raises
        (unless ``errors_ok``: then it is returned like any text)."""
        if not line.endswith(b"\r"):
            raise MachineError(f"garbled reply to {show(request)}: {show(line)}")
        line = line[:-1]
        if self.use_checksum:
            star = line.rfind(b"*")
            if star < 0:
                raise MachineError(f"garbled reply (no checksum) to {show(request)}: {show(line)}")
            body, ck = line[:star], line[star + 1 :]
            if not ck.isdigit() or int(ck) != checksum(body):
                raise MachineError(f"garbled reply (bad checksum) to {show(request)}: {show(line)}")
            line = body
        try:
            text = line.decode("ascii")
        except UnicodeDecodeError:
            raise MachineError(f"garbled reply to {show(request)}: {show(line)}") from None
        if not text.isprintable():
            raise MachineError(f"garbled reply to {show(request)}: {show(line)}")
        if not errors_ok and text.startswith(ERROR_REPLIES):
            raise MachineError(f"device replied {text!r} to {show(request)}")
        return text

    def _take_available(self, buf: bytearray) -> bool:
        """Whatever has arrived, without waiting (a process descheduled past its deadline may
        find the reply already there). True if anything came."""
        try:
            chunk = self.ser.read(4096) if self.ser is not None else b""
        except (serial.SerialException, OSError):
            return False
        buf += chunk
        return bool(chunk)

    # -- requests ------------------------------------------------------------------------------
    def ask(self, command: str, errors_ok: bool = False) -> str:
        req = self.encode(command)
        self.send(req)
        return self.check(self.line(req), req, errors_ok)

    def read_float(self, path: str) -> float:
        """A float property as printed (``inf`` and ``nan`` included: the caller judges)."""
        text = self.ask(f"r {path}")
        try:
            return float(text)
        except ValueError:
            raise MachineError(f"garbled value for {path}: {text!r}") from None

    def read_number(self, path: str) -> float:
        value = self.read_float(path)
        if not math.isfinite(value):
            raise MachineError(f"non-finite value for {path}: {value!r}")
        return value

    def read_int(self, path: str) -> int:
        """An integer property (``%u``, ``%d``, or ``%ud`` on 0.5.2-0.5.3: ``0d``)."""
        text = self.ask(f"r {path}")
        digits = text[:-1] if self.uint_suffix and text.endswith("d") else text
        try:
            return int(digits)
        except ValueError:
            raise MachineError(f"garbled value for {path}: {text!r}") from None

    def read_flags(self, path: str) -> tuple[int | None, str]:
        """An error register: (its bits, or None if the firmware cannot print it; a note)."""
        text = self.ask(f"r {path}")
        if text == "lu":
            return None, UNREADABLE_64
        digits = text[:-1] if self.uint_suffix and text.endswith("d") else text
        if not digits.isdigit():
            raise MachineError(f"garbled value for {path}: {text!r}")
        cut = " (as printed: the firmware cuts replies at 9 digits)"
        return int(digits), cut if len(text) >= R_REPLY_MAX else ""

    def write(self, path: str, value: float | int, then: str) -> tuple[str | None, str]:
        """``w path value`` then ``r then``: (the device's refusal of the write or None, the
        text read back)."""
        self.send_text(f"w {path} {fmt(value)}")
        req = self.encode(f"r {then}")
        self.send(req)
        first = self.check(self.line(req, alone=False), req, errors_ok=True)
        if not first.startswith(ERROR_REPLIES):
            self._nothing_more(req)
            return None, first
        # the write was refused: the read's own reply follows
        return first, self.check(self.line(req), req, errors_ok=True)

    def _nothing_more(self, request: bytes) -> None:
        if self.buf:
            extra = bytes(self.buf)
            self.buf.clear()
            raise MachineError(f"unexpected data after the reply to {show(request)}: {show(extra)}")


def fmt(value: float) -> str:
    if value == int(value) and abs(value) < 1e9:
        return str(int(value))
    return f"{value:.7g}"


def show(data: bytes) -> str:
    text = repr(data[:60])
    return text + ("…" if len(data) > 60 else "")
