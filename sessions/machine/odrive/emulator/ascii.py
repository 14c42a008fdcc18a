"""The ASCII protocol as the device speaks it (firmware 0.5.x ``ascii_protocol.cpp``, checked
line by line): one line in, the reply lines out.

- ``;`` starts a comment; an optional ``*CK`` checksum (XOR of the bytes before ``*``) is
  verified (a mismatch: the line is ignored, no reply) and, if sent, echoed on the reply; an
  empty line answers ``unknown command``;
- the command letter picks one function, as the firmware dispatches: ``c a T`` torque setpoint
  (torque control, feeds the watchdog), ``u a`` feeds the watchdog, ``f a`` replies
  ``pos vel`` (``%f``, float32, turns and turns/s), ``r path`` / ``w path value`` on the
  property tree (:mod:`.device`), ``sc`` clear errors, ``ss``/``se``/``sr``, ``i``, ``h``; the
  position/velocity/trajectory commands (``p q v t``) answer ``not implemented`` here: the rig
  runs in torque control only.

Arguments are read the way the firmware's ``sscanf`` reads them (:func:`scan`).
"""

from __future__ import annotations

import re
import struct
from collections.abc import Callable

from sessions.machine.odrive.emulator.device import (
    AXIS_COUNT,
    FIRMWARE,
    HARDWARE,
    Axis,
    Device,
)
from sessions.machine.odrive.protocol import MAX_LINE, checksum

_FLOAT = re.compile(rb"\s*([+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|inf(?:inity)?|nan))", re.I)
_UINT = re.compile(rb"\s*([+-]?\d+)")
_WORD = re.compile(rb"\s*(\S{1,255})")

INVALID_FORMAT = b"invalid command format"
INVALID_PROPERTY = b"invalid property"
NOT_IMPLEMENTED = b"not implemented"
UNKNOWN_COMMAND = b"unknown command"


def scan(text: bytes, spec: str) -> list[float | int | bytes]:
    """sscanf after the command word: ``u`` unsigned, ``f`` float, ``s`` word. Stops at the
    first conversion that fails, like sscanf; the count of results is sscanf's return."""
    out: list[float | int | bytes] = []
    pos = 0
    for conv in spec:
        pattern = _UINT if conv == "u" else _FLOAT if conv == "f" else _WORD
        m = pattern.match(text, pos)
        if not m:
            break
        tok = m.group(1)
        if conv == "u":
            out.append(int(tok) % (1 << 32))  # %u wraps negatives, as C does
        elif conv == "f":
            out.append(float(struct.unpack("f", struct.pack("f", float(tok)))[0]))
        else:
            out.append(tok)
        pos = m.end()
    return out


def format_value(value: float | int | bool) -> bytes:
    """As the firmware's 10-byte ``r`` buffer prints it: integers whole, floats ``%f`` cut to
    9 characters."""
    if isinstance(value, bool):
        return b"%d" % int(value)
    if isinstance(value, int):
        return b"%d" % value
    return (b"%f" % value)[:9]


def frame(reply: bytes, use_ck: bool, bad_ck: bool = False) -> bytes:
    """A reply line on the wire: ``reply*CK\\r\\n`` (a wrong CK: ``bad_ck``), or ``reply\\r\\n``."""
    if use_ck:
        ck = checksum(reply) ^ (0x55 if bad_ck else 0)
        return reply + b"*%d\r\n" % ck
    return reply + b"\r\n"


def split_line(line: bytes) -> tuple[bytes, bool, bool]:
    """(command, a checksum was sent, the line may be processed): the comment cut off, the
    checksum verified and cut off."""
    ck = 0
    star = -1
    for i, b in enumerate(line):
        if b == 0x3B:  # ';' starts a comment
            line = line[:i]
            break
        if star < 0:
            if b == 0x2A:  # '*'
                star = i + 1
            else:
                ck ^= b
    cmd = line[:MAX_LINE]
    use_ck = 0 <= star < len(cmd)
    if not use_ck:
        return cmd, False, True
    got = scan(cmd[star:], "u")
    return cmd[: star - 1], True, bool(got) and got[0] == ck


class RefusedError(Exception):
    """A command the device answers with an error line."""

    def __init__(self, reply: bytes) -> None:
        super().__init__(reply)
        self.reply = reply


Handler = Callable[[Device, bytes, float], list[bytes]]  # (device, the line, now) → replies


def _axis(dev: Device, cmd: bytes, spec: str) -> tuple[Axis, list[float | int | bytes]]:
    """The axis argument (always first) and the rest, parsed once for every axis command."""
    got = scan(cmd[1:], spec)
    if len(got) < len(spec):
        raise RefusedError(INVALID_FORMAT)
    if got[0] >= AXIS_COUNT:  # type: ignore[operator]
        raise RefusedError(b"invalid motor %d" % got[0])
    return dev.axes[int(got[0])], got[1:]


def torque(dev: Device, cmd: bytes, now: float) -> list[bytes]:
    """``c axis torque``: torque control at this setpoint; feeds the watchdog."""
    ax, (value,) = _axis(dev, cmd, "uf")
    dev.set_torque(ax, float(value), now)
    return []


def feedback(dev: Device, cmd: bytes, now: float) -> list[bytes]:
    """``f axis``: ``pos vel``."""
    ax, _ = _axis(dev, cmd, "u")
    return [b"%f %f" % dev.feedback(ax)]


def feed_watchdog(dev: Device, cmd: bytes, now: float) -> list[bytes]:
    """``u axis``: feed the watchdog, nothing else."""
    ax, _ = _axis(dev, cmd, "u")
    dev.feed(ax, now)
    return []


def _property(dev: Device, name: bytes) -> tuple[Axis | None, str]:
    try:
        found = dev.find(name.decode("ascii"))
    except UnicodeDecodeError:
        found = None
    if found is None:
        raise RefusedError(INVALID_PROPERTY)
    return found


def read_property(dev: Device, cmd: bytes, now: float) -> list[bytes]:
    """``r path``: the value."""
    got = scan(cmd[1:], "s")
    if not got:
        raise RefusedError(INVALID_FORMAT)
    return [format_value(dev.get(*_property(dev, got[0])))]  # type: ignore[arg-type]


def write_property(dev: Device, cmd: bytes, now: float) -> list[bytes]:
    """``w path value``: no reply when it is written."""
    got = scan(cmd[1:], "ss")
    if not got:
        raise RefusedError(INVALID_FORMAT)
    ax, name = _property(dev, got[0])  # type: ignore[arg-type]
    prop = dev.writable(ax, name)
    if len(got) < 2 or prop is None or ax is None:
        raise RefusedError(NOT_IMPLEMENTED)
    raw: bytes = got[1]  # type: ignore[assignment]
    value: float | int | bool
    if prop.kind is float:
        parsed = scan(raw, "f")
        if not parsed:
            raise RefusedError(NOT_IMPLEMENTED)
        value = float(parsed[0])
    else:
        m = _UINT.match(raw)
        if not m:
            raise RefusedError(NOT_IMPLEMENTED)
        value = int(m.group(1))
        if prop.kind is bool:
            value = bool(value)
    dev.write(ax, name, value, now)
    return []


def system(dev: Device, cmd: bytes, now: float) -> list[bytes]:
    """``sc`` clear errors, ``se`` erase the configuration, ``sr`` reboot, ``ss`` save."""
    sub = cmd[1:2]
    if sub == b"c":
        dev.clear_errors()
    elif sub in (b"e", b"r"):
        dev.reset_config(now, reboot=sub == b"r")
    return []


def info(dev: Device, cmd: bytes, now: float) -> list[bytes]:
    return [
        b"Hardware version: %d.%d-%dV" % HARDWARE,
        b"Firmware version: %d.%d.%d" % FIRMWARE,
        b"Serial number: 306135393235",
    ]


def help_text(dev: Device, cmd: bytes, now: float) -> list[bytes]:
    return [
        b"Please see documentation for more details",
        b"",
        b"Available commands syntax reference:",
        b"Torque: c axis T",
        b"Feedback: f axis",
        b"Properties start at odrive root, such as axis0.requested_state",
        b"Read: r property",
        b"Write: w property value",
    ]


def _answer(reply: bytes) -> Handler:
    def handler(dev: Device, cmd: bytes, now: float) -> list[bytes]:
        return [reply]

    return handler


# The firmware's dispatch: one function per command letter.
COMMANDS: dict[bytes, Handler] = {
    b"c": torque,
    b"f": feedback,
    b"u": feed_watchdog,
    b"r": read_property,
    b"w": write_property,
    b"s": system,
    b"i": info,
    b"h": help_text,
    **dict.fromkeys((b"p", b"q", b"v", b"t"), _answer(NOT_IMPLEMENTED)),  # torque control only
    b"e": _answer(INVALID_FORMAT),
}
_UNKNOWN = _answer(UNKNOWN_COMMAND)


class AsciiProtocol:
    """The device's line interpreter. ``use_ck`` says whether the last line processed carried
    a checksum (its reply then carries one too)."""

    def __init__(self, device: Device) -> None:
        self.device = device
        self.use_ck = False

    def process_line(self, line: bytes, now: float) -> list[bytes]:
        """One line in (without its end); the reply lines (without checksum and end) out."""
        cmd, use_ck, ok = split_line(line)
        dev = self.device
        if not ok:
            dev.ignored_checksum += 1
            return []  # silently ignored, as the firmware does
        dev.lines += 1
        self.use_ck = use_ck
        try:
            return COMMANDS.get(cmd[:1], _UNKNOWN)(dev, cmd, now)
        except RefusedError as refused:
            return [refused.reply]
