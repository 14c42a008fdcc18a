"""The ASCII protocol as the device speaks it (firmware 0.5.x ``ascii_protocol.cpp``, checked
line by line): one line in, the reply lines out, as the device's firmware version does it.

- ``;`` starts a comment; an optional ``*CK`` checksum (XOR of the bytes before ``*``) is
  verified (a mismatch: the line is ignored, no reply) and, if sent, echoed on the reply; an
  empty line answers ``unknown command`` (0.5.2+; 0.5.1 says nothing);
- the command letter picks one function, as the firmware dispatches: ``c a T`` torque setpoint
  (torque control, feeds the watchdog), ``u a`` feeds the watchdog, ``f a`` replies
  ``pos vel`` (``%f``, float32, turns and turns/s), ``r path`` / ``w path value`` on the
  property tree (:mod:`.device`), ``sc`` clear errors (0.5.2+; 0.5.1 ignores it),
  ``ss``/``se``/``sr``, ``i``, ``h``; the position/velocity/trajectory commands (``p q v t``)
  answer ``not implemented`` here: the rig runs in torque control only;
- ``r`` prints as the firmware's formatter does, into its 10-byte buffer (9 characters, cut
  silently): unsigned error registers ``%ud`` in 0.5.2-0.5.3 (``0d``); 64-bit ones (``motor.error``
  from 0.5.2, ``serial_number``) ``lu`` on the release builds (newlib-nano has no ``%llu``), which
  cannot parse them either (a write answers ``not implemented``); 0.5.2-0.5.3 release builds
  answer ``not implemented`` to every enum write (the CI-compiler bug fixed in 0.5.4).

Arguments are read the way the firmware's ``sscanf`` reads them (:func:`scan`).
"""

from __future__ import annotations

import re
import struct
from collections.abc import Callable

from sessions.machine.odrive.emulator.device import (
    AXIS_COUNT,
    HARDWARE,
    Axis,
    Device,
    Kind,
)
from sessions.machine.odrive.protocol import MAX_LINE, R_REPLY_MAX, checksum

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


def format_value(value: float | int | bool, kind: Kind = "i32", dev: Device | None = None) -> bytes:
    """As the firmware's 10-byte ``r`` buffer prints it: cut to 9 characters, floats ``%f``,
    integers by their type and the firmware (``%ud``, ``lu``: see the module's docstring)."""
    fw = dev.fw if dev is not None else None
    if kind == "bool" or isinstance(value, bool):
        return b"1" if value else b"0"
    if kind == "f32" or isinstance(value, float):
        text = b"%f" % value
    elif kind in ("flags64", "u64") and fw is not None and _nano(dev) and fw.motor_error_64:
        text = b"lu"  # "%llu" on newlib-nano
    elif kind == "flags" and fw is not None and fw.uint_suffix:
        text = b"%dd" % value  # "%ud": an unsigned, then a literal d
    else:
        text = b"%d" % value
    return text[:R_REPLY_MAX]


def _nano(dev: Device | None) -> bool:
    return dev is not None and dev.rig.build == "release"


def _refuses_write(dev: Device, kind: Kind) -> bool:
    """This build cannot parse a value of this kind (the write answers ``not implemented``)."""
    if not _nano(dev):
        return False
    fw = dev.fw
    if kind in ("flags64", "u64") and fw.motor_error_64:
        return True
    return fw.enum_write_bug and kind in ("enum", "flags")


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
    ax, name = _property(dev, got[0])  # type: ignore[arg-type]
    return [format_value(dev.get(ax, name), dev.kind(ax, name), dev)]


def write_property(dev: Device, cmd: bytes, now: float) -> list[bytes]:
    """``w path value``: no reply when it is written."""
    got = scan(cmd[1:], "ss")
    if not got:
        raise RefusedError(INVALID_FORMAT)
    ax, name = _property(dev, got[0])  # type: ignore[arg-type]
    prop = dev.writable(ax, name)
    if len(got) < 2 or prop is None or ax is None or _refuses_write(dev, prop.kind):
        raise RefusedError(NOT_IMPLEMENTED)
    raw: bytes = got[1]  # type: ignore[assignment]
    value: float | int | bool
    if prop.kind == "f32":
        parsed = scan(raw, "f")
        if not parsed:
            raise RefusedError(NOT_IMPLEMENTED)
        value = float(parsed[0])
    else:
        m = _UINT.match(raw)
        if not m:
            raise RefusedError(NOT_IMPLEMENTED)
        value = int(m.group(1))
        if prop.kind == "bool":
            value = bool(value)
    dev.write(ax, name, value, now)
    return []


def system(dev: Device, cmd: bytes, now: float) -> list[bytes]:
    """``sc`` clear errors, ``se`` erase the configuration, ``sr`` reboot, ``ss`` save."""
    sub = cmd[1:2]
    if sub == b"c" and dev.fw.has_sc:  # 0.5.1 has no "sc": nothing happens
        dev.clear_errors()
    elif sub in (b"e", b"r"):
        dev.reset_config(now, reboot=sub == b"r")
    return []


def info(dev: Device, cmd: bytes, now: float) -> list[bytes]:
    return [
        b"Hardware version: %d.%d-%dV" % HARDWARE,
        b"Firmware version: %d.%d.%d" % dev.fw.version,
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
        if not cmd and not dev.fw.empty_line_reply:
            return []  # 0.5.1: "else if (cmd[0] != 0)": an empty line says nothing
        try:
            return COMMANDS.get(cmd[:1], _UNKNOWN)(dev, cmd, now)
        except RefusedError as refused:
            return [refused.reply]
