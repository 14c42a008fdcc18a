"""An ODrive v3.x (firmware 0.5.x) on a pseudo-terminal: the ASCII protocol subset a torque
controlled rig uses, in front of the engine's plant (1) and a simulated user.

The host opens the pty's slave path like any serial device; the emulator serves the master end,
in raw mode (``tty.setraw``) so no line discipline rewrites bytes. What it does, as the firmware
does (``ascii_protocol.cpp`` of 0.5.x, checked line by line):

- lines end on ``\\r``, ``\\n`` or ``!``; over 256 characters without an end, the line is
  dropped; ``;`` starts a comment; an optional ``*CK`` checksum (XOR of the bytes before ``*``)
  is verified (mismatch: ignored, no reply) and echoed on the reply; an empty line answers
  ``unknown command``;
- ``c a T`` torque setpoint (switches to torque control, feeds the watchdog), ``u a`` feeds the
  watchdog, ``f a`` replies ``pos vel`` (``%f``, float32, turns and turns/s), ``r path`` /
  ``w path value`` on the property tree below, ``sc`` clear errors, ``ss``/``se``/``sr``,
  ``i``, ``h``; the position/velocity/trajectory commands (``p q v t``) answer
  ``not implemented`` here: the rig runs in torque control only;
- the axis state machine: ``requested_state`` 8 enters closed-loop control if the axis has no
  error, 1 goes idle;
- in closed loop, torque mode: the setpoint passes the torque-mode velocity limiter
  (clamped to ``[(-vel_limit - v)·vel_gain, (vel_limit - v)·vel_gain]`` when
  ``enable_torque_mode_vel_limit``), then ``torque_lim`` and ``current_lim·torque_constant``;
  ``|v| > vel_limit_tolerance·vel_limit`` with ``enable_overspeed_error`` sets the controller's
  OVERSPEED error, the axis error CONTROLLER_FAILED and drops to idle;
- the watchdog (``config.enable_watchdog``, ``config.watchdog_timeout``): if not fed within the
  timeout, axis error WATCHDOG_TIMER_EXPIRED and idle, torque zero. It is checked on the physics
  clock, so the plant sees zero torque from the expiry on (to one physics step), however late the
  emulator's thread runs.

The physics runs on its own fixed-step clock (``physics_rate``, 8 kHz like the firmware's control
loop) against wall time: before anything is answered the plant is brought up to now, the motor
torque held over each step. The simulated person pushes while the axis is in closed loop (they
take the handle when the machine is ready) and lets go otherwise.

Fault injection (:meth:`OdriveEmulator.inject`) makes the line misbehave the way real ones do:
garbage, short replies, partial lines, silence, unsolicited lines, bad checksums.
"""

from __future__ import annotations

import contextlib
import gc
import math
import multiprocessing as mp
import os
import re
import select
import signal
import struct
import threading
import time
import tty
from array import array
from collections import deque
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from typing import Literal

from sessions.config import SessionConfig, UserConfig
from sessions.machine.protocol import (
    AXIS_ERROR_CONTROLLER_FAILED,
    AXIS_ERROR_WATCHDOG_TIMER_EXPIRED,
    AXIS_STATE_CLOSED_LOOP_CONTROL,
    AXIS_STATE_IDLE,
    CONTROL_MODE_TORQUE_CONTROL,
    CONTROLLER_ERROR_OVERSPEED,
    MAX_LINE,
    checksum,
)
from sessions.people import SimulatedUser
from sessions.plant import Plant

AXIS_COUNT = 2
FIRMWARE = (0, 5, 6)
HARDWARE = (3, 6, 56)
TWO_PI = 2.0 * math.pi

Injection = Literal["garbage", "short", "partial", "silence", "extra", "bad-checksum"]
INJECTIONS: tuple[str, ...] = ("garbage", "short", "partial", "silence", "extra", "bad-checksum")


@dataclass(frozen=True)
class EmulatorConfig:
    """The emulated rig: who pushes, the handle's inertia and the drive train."""

    user: UserConfig = field(default_factory=UserConfig)
    inertia: float = 0.1  # J at the handle, kg·m²
    gear_ratio: float = 1.0  # motor turns per handle turn
    direction: int = 1  # +1: motor and handle turn the same way
    axis: int = 0  # the axis the handle is on
    physics_rate: float = 8000.0  # Hz
    seed: int = 1
    initial_turns: float = 0.0  # encoder position at power-up, motor turns
    current_lim: float = 60.0  # A (motor.config.current_lim default of this rig)
    torque_constant: float = 0.35  # N·m/A: 21 N·m at the current limit
    vbus: float = 24.0

    def __post_init__(self) -> None:
        if self.direction not in (1, -1):
            raise ValueError("direction must be +1 or -1")
        if not (self.gear_ratio > 0 and self.inertia > 0 and self.physics_rate >= 100):
            raise ValueError("gear_ratio and inertia must be positive, physics_rate ≥ 100 Hz")
        if self.axis not in (0, 1):
            raise ValueError("axis must be 0 or 1")

    @classmethod
    def from_session(cls, cfg: SessionConfig, **kw: object) -> EmulatorConfig:
        """The person and handle of a scenario, on an emulated drive."""
        return cls(user=cfg.user, inertia=cfg.machine.inertia, seed=cfg.seed, **kw)  # type: ignore[arg-type]


@dataclass(frozen=True)
class EmulatorSnapshot:
    """The device's state at one instant (physics brought up to ``t``), for tests and tools."""

    t: float  # monotonic time of the snapshot
    q: float  # handle angle, rad
    w: float  # handle velocity, rad/s
    input_torque: float  # motor N·m, as last commanded
    applied_torque: float  # motor N·m acting on the plant now (after state, limits)
    current_state: int
    error: int
    controller_error: int
    watchdog_enabled: bool
    last_feed: float  # monotonic time of the last watchdog feed (-inf: never)
    watchdog_tripped_at: float | None  # physics time of the last expiry
    lines: int  # lines processed
    ignored_checksum: int  # lines ignored for a bad checksum
    engaged: bool  # the simulated person is pushing
    user_work: float  # true ∫ τ w dt of the person, J


@dataclass
class _Prop:
    kind: type
    value: float | int | bool
    writable: bool = True


def _axis_props(rig: EmulatorConfig) -> dict[str, _Prop]:
    return {
        "error": _Prop(int, 0),
        "current_state": _Prop(int, AXIS_STATE_IDLE, writable=False),
        "requested_state": _Prop(int, 0),
        "config.enable_watchdog": _Prop(bool, False),
        "config.watchdog_timeout": _Prop(float, 0.0),
        "controller.error": _Prop(int, 0),
        "controller.input_torque": _Prop(float, 0.0),
        "controller.config.control_mode": _Prop(int, 3),
        "controller.config.input_mode": _Prop(int, 1),
        "controller.config.vel_limit": _Prop(float, 2.0),
        "controller.config.vel_gain": _Prop(float, 1.0 / 6.0),
        "controller.config.vel_limit_tolerance": _Prop(float, 1.2),
        "controller.config.enable_torque_mode_vel_limit": _Prop(bool, True),
        "controller.config.enable_overspeed_error": _Prop(bool, True),
        "motor.error": _Prop(int, 0),
        "motor.config.torque_lim": _Prop(float, math.inf),
        "motor.config.current_lim": _Prop(float, rig.current_lim),
        "motor.config.torque_constant": _Prop(float, rig.torque_constant),
        "encoder.error": _Prop(int, 0),
        "encoder.pos_estimate": _Prop(float, 0.0, writable=False),
        "encoder.vel_estimate": _Prop(float, 0.0, writable=False),
    }


class _Axis:
    """One axis' property tree, with direct references to the properties the physics reads."""

    __slots__ = (
        "props", "last_feed", "tripped_at", "applied", "wd_enable", "wd_timeout", "state",
        "error", "ctrl_error", "input_torque", "control_mode", "vel_limit", "vel_gain",
        "vel_tolerance", "torque_mode_vel_limit", "overspeed_error", "torque_lim",
        "current_lim", "torque_constant",
    )  # fmt: skip

    def __init__(self, rig: EmulatorConfig) -> None:
        p = self.props = _axis_props(rig)
        self.last_feed = -math.inf
        self.tripped_at: float | None = None
        self.applied = 0.0
        self.wd_enable = p["config.enable_watchdog"]
        self.wd_timeout = p["config.watchdog_timeout"]
        self.state = p["current_state"]
        self.error = p["error"]
        self.ctrl_error = p["controller.error"]
        self.input_torque = p["controller.input_torque"]
        self.control_mode = p["controller.config.control_mode"]
        self.vel_limit = p["controller.config.vel_limit"]
        self.vel_gain = p["controller.config.vel_gain"]
        self.vel_tolerance = p["controller.config.vel_limit_tolerance"]
        self.torque_mode_vel_limit = p["controller.config.enable_torque_mode_vel_limit"]
        self.overspeed_error = p["controller.config.enable_overspeed_error"]
        self.torque_lim = p["motor.config.torque_lim"]
        self.current_lim = p["motor.config.current_lim"]
        self.torque_constant = p["motor.config.torque_constant"]

    def get(self, name: str) -> float:
        return self.props[name].value  # type: ignore[return-value]

    def set(self, name: str, value: float | int | bool) -> None:
        self.props[name].value = value


_FLOAT = re.compile(rb"\s*([+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|inf(?:inity)?|nan))", re.I)
_UINT = re.compile(rb"\s*([+-]?\d+)")
_WORD = re.compile(rb"\s*(\S{1,255})")


def _scan(text: bytes, spec: str) -> list[float | int | bytes]:
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


def _f32(x: float) -> float:
    try:
        return struct.unpack("f", struct.pack("f", x))[0]
    except OverflowError:
        return math.copysign(math.inf, x)


class OdriveEmulator:
    """Serve one emulated ODrive on a new pty. ``start()`` runs it in a thread (tests, tools);
    ``serve_forever()`` runs it in the calling thread (``ergoseek emulate-odrive``)."""

    def __init__(self, rig: EmulatorConfig | None = None) -> None:
        self.rig = rig or EmulatorConfig()
        r = self.rig
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        self.h = 1.0 / r.physics_rate
        self.turns_per_rad = r.direction * r.gear_ratio / TWO_PI  # handle rad → motor turns
        self.handle_per_motor_torque = r.direction * r.gear_ratio
        self.lock = threading.RLock()
        self.torque_log = _TorqueLog()
        self.log: deque[tuple[float, str]] = deque(maxlen=10_000)
        self.log_total = 0
        self._wake_r, self._wake_w = os.pipe()
        self._thread: threading.Thread | None = None
        self._running = False
        self._inject: tuple[str, int | None] | None = None
        self._use_ck = False
        self._reset_device()
        self.t0 = time.monotonic()
        self.k = 0  # physics steps since t0

    # -- device state ----------------------------------------------------------------------
    def _reset_device(self) -> None:
        r = self.rig
        self.axes = [_Axis(r) for _ in range(AXIS_COUNT)]
        self.rig_axis = self.axes[r.axis]
        self.plant = Plant(r.inertia)
        self.user = SimulatedUser(r.user, self.h, r.seed)
        self.engaged = False
        self.rx = bytearray()
        self.read_active = True
        self.lines = 0
        self.ignored_checksum = 0

    @property
    def t_phys(self) -> float:
        return self.t0 + self.k * self.h

    def _motor_pos(self) -> float:
        return self.plant.q * self.turns_per_rad + self.rig.initial_turns

    def _motor_vel(self) -> float:
        return self.plant.w * self.turns_per_rad

    def _note(self, entry: tuple[float, str]) -> None:
        self.log.append(entry)
        self.log_total += 1

    def _trip(self, ax: _Axis, bits: int, at: float, why: str) -> None:
        ax.error.value = int(ax.error.value) | bits
        ax.state.value = AXIS_STATE_IDLE
        ax.applied = 0.0
        self._note((at, why))

    def _step(self) -> None:
        """One physics step starting at t_phys: checks, torque, plant."""
        ts = self.t_phys
        h = self.h
        for ax in self.axes:
            if ax.wd_enable.value and ts - ax.last_feed > ax.wd_timeout.value:
                if not ax.error.value & AXIS_ERROR_WATCHDOG_TIMER_EXPIRED:  # type: ignore[operator]
                    ax.tripped_at = ts
                    self._trip(ax, AXIS_ERROR_WATCHDOG_TIMER_EXPIRED, ts, "watchdog timer expired")
        ax = self.rig_axis
        v = self.plant.w * self.turns_per_rad
        torque = 0.0
        closed = ax.state.value == AXIS_STATE_CLOSED_LOOP_CONTROL
        if closed:
            vl = ax.vel_limit.value
            if ax.overspeed_error.value and abs(v) > ax.vel_tolerance.value * vl:  # type: ignore[operator]
                ax.ctrl_error.value |= CONTROLLER_ERROR_OVERSPEED  # type: ignore[operator]
                self._trip(ax, AXIS_ERROR_CONTROLLER_FAILED, ts, "overspeed")
                closed = False
            elif ax.control_mode.value == CONTROL_MODE_TORQUE_CONTROL:
                torque = ax.input_torque.value  # type: ignore[assignment]
                if ax.torque_mode_vel_limit.value:
                    g = ax.vel_gain.value
                    hi, lo = (vl - v) * g, (-vl - v) * g  # type: ignore[operator]
                    torque = hi if torque > hi else lo if torque < lo else torque
                lim = ax.current_lim.value * ax.torque_constant.value  # type: ignore[operator]
                tl = ax.torque_lim.value
                if tl < lim:  # type: ignore[operator]
                    lim = tl
                torque = lim if torque > lim else -lim if torque < -lim else torque  # type: ignore[operator]
        ax.applied = torque
        if closed != self.engaged:
            self.engaged = closed
            self._note((ts, "person takes the handle" if closed else "person lets go"))
        u = torque * self.handle_per_motor_torque
        plant, user = self.plant, self.user
        if closed:
            plant.sample_torque(user)
            plant.advance(u, h, user)
            user.advance(h)
        else:
            plant.user_torque = 0.0
            plant.advance(u, h, _NOBODY)  # type: ignore[arg-type]
        self.k += 1

    def _catch_up(self, now: float) -> None:
        n = int((now - self.t0) / self.h)
        while self.k < n:
            self._step()

    # -- protocol ----------------------------------------------------------------------------
    def _feed(self, ax: _Axis, now: float) -> None:
        ax.last_feed = now

    def _prop(self, name: bytes) -> tuple[_Axis | None, str] | None:
        try:
            path = name.decode("ascii")
        except UnicodeDecodeError:
            return None
        for i, ax in enumerate(self.axes):
            prefix = f"axis{i}."
            if path.startswith(prefix) and path[len(prefix) :] in ax.props:
                return ax, path[len(prefix) :]
        if path in _ROOT_PROPS:
            return None, path
        return None

    def _get(self, ax: _Axis | None, name: str) -> float | int | bool:
        if ax is None:
            return {
                "fw_version_major": FIRMWARE[0],
                "fw_version_minor": FIRMWARE[1],
                "fw_version_revision": FIRMWARE[2],
                "hw_version_major": HARDWARE[0],
                "hw_version_minor": HARDWARE[1],
                "hw_version_variant": HARDWARE[2],
                "vbus_voltage": self.rig.vbus,
                "serial_number": 0x3061_3539_3235,
            }[name]
        if ax is self.rig_axis and name == "encoder.pos_estimate":
            return _f32(self._motor_pos())
        if ax is self.rig_axis and name == "encoder.vel_estimate":
            return _f32(self._motor_vel())
        return ax.props[name].value

    def _set(self, ax: _Axis | None, name: str, raw: bytes, now: float) -> bool:
        if ax is None or not ax.props[name].writable:
            return False
        prop = ax.props[name]
        if prop.kind is float:
            got = _scan(raw, "f")
            if not got:
                return False
            value: float | int | bool = float(got[0])
        else:
            m = _UINT.match(raw)
            if not m:
                return False
            value = int(m.group(1))
            if prop.kind is bool:
                value = bool(value)
        if name == "requested_state":
            ax.set(name, value)
            self._request_state(ax, int(value), now)
            return True
        prop.value = value
        return True

    def _request_state(self, ax: _Axis, state: int, now: float) -> None:
        if state == AXIS_STATE_CLOSED_LOOP_CONTROL:
            if int(ax.get("error")) == 0 and ax is self.rig_axis:
                ax.set("current_state", AXIS_STATE_CLOSED_LOOP_CONTROL)
                self._note((now, "closed loop"))
            else:
                self._note((now, "closed loop refused (axis error or no motor)"))
        elif state == AXIS_STATE_IDLE:
            ax.set("current_state", AXIS_STATE_IDLE)
            self._note((now, "idle"))

    def _clear_errors(self) -> None:
        for ax in self.axes:
            for name in ("error", "controller.error", "motor.error", "encoder.error"):
                ax.set(name, 0)

    def _process_line(self, line: bytes, now: float) -> list[bytes]:
        """One line in; the reply lines (without checksum and line end) out."""
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
        if use_ck:
            got = _scan(cmd[star:], "u")
            if not got or got[0] != ck:
                self.ignored_checksum += 1
                return []  # silently ignored, as the firmware does
            cmd = cmd[: star - 1]
        self.lines += 1
        self._use_ck = use_ck
        letter = cmd[:1]
        rest = cmd[1:]
        if letter == b"c":
            got = _scan(rest, "uf")
            if len(got) < 2:
                return [b"invalid command format"]
            if got[0] >= AXIS_COUNT:
                return [b"invalid motor %d" % got[0]]
            ax = self.axes[int(got[0])]
            ax.set("controller.config.control_mode", CONTROL_MODE_TORQUE_CONTROL)
            ax.set("controller.input_torque", float(got[1]))
            self._feed(ax, now)
            if ax is self.rig_axis:
                self.torque_log.append(now, float(got[1]))
            return []
        if letter == b"f":
            got = _scan(rest, "u")
            if len(got) < 1:
                return [b"invalid command format"]
            if got[0] >= AXIS_COUNT:
                return [b"invalid motor %d" % got[0]]
            ax = self.axes[int(got[0])]
            if ax is self.rig_axis:
                pos, vel = _f32(self._motor_pos()), _f32(self._motor_vel())
            else:
                pos = vel = 0.0
            return [b"%f %f" % (pos, vel)]
        if letter == b"u":
            got = _scan(rest, "u")
            if len(got) < 1:
                return [b"invalid command format"]
            if got[0] >= AXIS_COUNT:
                return [b"invalid motor %d" % got[0]]
            self._feed(self.axes[int(got[0])], now)
            return []
        if letter == b"r":
            got = _scan(rest, "s")
            if not got:
                return [b"invalid command format"]
            found = self._prop(got[0])  # type: ignore[arg-type]
            if found is None:
                return [b"invalid property"]
            value = self._get(*found)
            return [_format_value(value)]
        if letter == b"w":
            got = _scan(rest, "ss")
            if not got:
                return [b"invalid command format"]
            found = self._prop(got[0])  # type: ignore[arg-type]
            if found is None:
                return [b"invalid property"]
            if len(got) < 2 or not self._set(found[0], found[1], got[1], now):  # type: ignore[arg-type]
                return [b"not implemented"]
            return []
        if letter == b"s":
            sub = cmd[1:2]
            if sub == b"c":
                self._clear_errors()
            elif sub == b"e":
                self.axes = [_Axis(self.rig) for _ in range(AXIS_COUNT)]
                self.rig_axis = self.axes[self.rig.axis]
            elif sub == b"r":
                self.axes = [_Axis(self.rig) for _ in range(AXIS_COUNT)]
                self.rig_axis = self.axes[self.rig.axis]
                self._note((now, "reboot"))
            return []
        if letter == b"i":
            return [
                b"Hardware version: %d.%d-%dV" % HARDWARE,
                b"Firmware version: %d.%d.%d" % FIRMWARE,
                b"Serial number: 306135393235",
            ]
        if letter == b"h":
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
        if letter in (b"p", b"q", b"v", b"t"):
            return [b"not implemented"]
        if letter == b"e":
            return [b"invalid command format"]
        return [b"unknown command"]

    def _frame(self, reply: bytes, use_ck: bool, bad_ck: bool = False) -> bytes:
        if use_ck:
            ck = checksum(reply) ^ (0x55 if bad_ck else 0)
            return reply + b"*%d\r\n" % ck
        return reply + b"\r\n"

    def _handle(self, line: bytes, now: float) -> bytes:
        inj = self._take_injection()
        if inj == "silence":
            return b""
        replies = self._process_line(line, now)
        use_ck = self._use_ck
        if inj is None or (not replies and inj != "extra"):
            if inj is not None and inj != "extra":
                self._give_back(inj)  # nothing to corrupt: keep it for the next reply
            return b"".join(self._frame(r, use_ck) for r in replies)
        if inj == "garbage":
            return b"\x8f\x00#%&\xfe\xa5" + os.urandom(3).replace(b"\n", b"x") + b"\r\n"
        if inj == "short":
            return self._frame(replies[0].split(b" ")[0][:3], use_ck)
        if inj == "partial":
            return self._frame(replies[0], use_ck)[:-4]
        if inj == "bad-checksum":
            return b"".join(self._frame(r, True, bad_ck=True) for r in replies)
        if inj == "extra":
            out = b"".join(self._frame(r, use_ck) for r in replies)
            return out + self._frame(b"0.000000 0.000000", use_ck)
        return b""

    def _take_injection(self) -> str | None:
        if self._inject is None:
            return None
        kind, count = self._inject
        if count is None:
            return kind
        count -= 1
        self._inject = (kind, count) if count > 0 else None
        return kind

    def _give_back(self, kind: str) -> None:
        if self._inject is None:
            self._inject = (kind, 1)
        elif self._inject[1] is not None:
            self._inject = (kind, self._inject[1] + 1)

    def _receive(self, data: bytes, now: float) -> None:
        out = bytearray()
        for b in data:
            if b in (0x0D, 0x0A, 0x21):  # \r \n !
                if self.read_active:
                    out += self._handle(bytes(self.rx), now)
                self.rx.clear()
                self.read_active = True
            else:
                if len(self.rx) >= MAX_LINE:
                    self.rx.clear()
                    self.read_active = False
                if self.read_active:
                    self.rx.append(b)
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
            self._catch_up(now)
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
        if kind is not None and kind not in INJECTIONS:
            raise ValueError(f"unknown injection {kind!r}; one of {', '.join(INJECTIONS)}")
        with self.lock:
            self._inject = None if kind is None else (kind, count)

    def snapshot(self) -> EmulatorSnapshot:
        now = time.monotonic()
        with self.lock:
            self._catch_up(now)
            ax = self.rig_axis
            return EmulatorSnapshot(
                t=now,
                q=self.plant.q,
                w=self.plant.w,
                input_torque=float(ax.get("controller.input_torque")),
                applied_torque=ax.applied,
                current_state=int(ax.get("current_state")),
                error=int(ax.get("error")),
                controller_error=int(ax.get("controller.error")),
                watchdog_enabled=bool(ax.get("config.enable_watchdog")),
                last_feed=ax.last_feed,
                watchdog_tripped_at=ax.tripped_at,
                lines=self.lines,
                ignored_checksum=self.ignored_checksum,
                engaged=self.engaged,
                user_work=self.plant.user_work,
            )

    def torques_since(self, t: float) -> list[tuple[float, float]]:
        """``c`` setpoints (arrival time, motor N·m) received after monotonic time t."""
        with self.lock:
            return self.torque_log.since(t)

    def events(self) -> list[tuple[float, str]]:
        with self.lock:
            return list(self.log)


class _TorqueLog:
    """Arrival time and value of every torque setpoint, in flat arrays (no per-entry objects
    for the garbage collector to walk), the newest ``capacity`` kept."""

    def __init__(self, capacity: int = 1 << 18) -> None:  # 4 MB: 4 min at 1 kHz
        self.t = array("d", bytes(8 * capacity))
        self.v = array("d", bytes(8 * capacity))
        self.capacity = capacity
        self.n = 0

    def append(self, t: float, v: float) -> None:
        i = self.n % self.capacity
        self.t[i] = t
        self.v[i] = v
        self.n += 1

    def since(self, t: float) -> list[tuple[float, float]]:
        out: list[tuple[float, float]] = []
        n, cap = self.n, self.capacity
        for k in range(n - 1, max(-1, n - cap - 1), -1):
            ts = self.t[k % cap]
            if ts <= t:
                break
            out.append((ts, self.v[k % cap]))
        out.reverse()
        return out


class EmulatorProcess:
    """The emulator in its own process (spawn), driven over a pipe.

    What the tests and benchmarks use: a device answers on its own clock, and nothing in the
    host process (its garbage collector, its GIL) may delay it. Offers the same observation
    and fault-injection calls as :class:`OdriveEmulator`."""

    def __init__(
        self, rig: EmulatorConfig | None = None, timeout: float = 30.0, *, realtime: bool = True
    ) -> None:
        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(
            target=_serve_in_child,
            args=(child, rig or EmulatorConfig(), realtime),
            daemon=True,
            name="odrive-emulator",
        )
        self._proc.start()
        child.close()
        if not self._conn.poll(timeout):
            self._proc.kill()
            raise RuntimeError("the ODrive emulator did not start")
        self.path: str = self._conn.recv()
        self.pid: int = self._proc.pid

    def _call(self, name: str, *args: object) -> object:
        self._conn.send((name, args))
        if not self._conn.poll(10.0):
            raise TimeoutError(f"the emulator did not answer {name}")
        result = self._conn.recv()
        if isinstance(result, Exception):
            raise result
        return result

    def snapshot(self) -> EmulatorSnapshot:
        return self._call("snapshot")  # type: ignore[return-value]

    def inject(self, kind: Injection | None, count: int | None = 1) -> None:
        self._call("inject", kind, count)

    def torques_since(self, t: float) -> list[tuple[float, float]]:
        return self._call("torques_since", t)  # type: ignore[return-value]

    def events(self) -> list[tuple[float, str]]:
        return self._call("events")  # type: ignore[return-value]

    def close(self) -> None:
        if self._proc.is_alive():
            with contextlib.suppress(OSError, EOFError, TimeoutError):
                self._call("close")
            self._proc.join(2.0)
            if self._proc.is_alive():
                self._proc.kill()
                self._proc.join(1.0)
        self._conn.close()

    def __enter__(self) -> EmulatorProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def device_priority(priority: int = 60) -> bool:
    """Run the calling process as a device would: SCHED_FIFO above the worker's default (50),
    so it answers within microseconds of a request however busy the host is. Quietly False
    when not permitted."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError):
        return False
    return True


def _serve_in_child(control: Connection, rig: EmulatorConfig, realtime: bool) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if realtime:
        device_priority()
    emu = OdriveEmulator(rig)
    gc.collect()
    gc.freeze()  # the long-lived state stays out of every collection
    control.send(emu.path)
    try:
        emu.serve_forever(control)
    finally:
        emu.close()


class _Nobody:
    """Nobody on the handle: zero torque."""

    @staticmethod
    def torque(q: float, w: float) -> float:
        return 0.0


_NOBODY = _Nobody()
_ROOT_PROPS = frozenset(
    {
        "fw_version_major",
        "fw_version_minor",
        "fw_version_revision",
        "hw_version_major",
        "hw_version_minor",
        "hw_version_variant",
        "vbus_voltage",
        "serial_number",
    }
)


def _format_value(value: float | int | bool) -> bytes:
    """As the firmware's 10-byte ``r`` buffer prints it: integers whole, floats ``%f`` cut to
    9 characters."""
    if isinstance(value, bool):
        return b"%d" % int(value)
    if isinstance(value, int):
        return b"%d" % value
    return (b"%f" % value)[:9]
