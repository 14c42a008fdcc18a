"""The emulated ODrive itself: its property tree, the axis state machine, the torque-mode
limits, watchdog and error registers of firmware 0.5.1 … 0.5.6 (:class:`Firmware`, chosen by
``EmulatorConfig.firmware``), and the physics behind them: the engine's plant (1) with a
simulated person on the handle. No I/O and no protocol: :mod:`.ascii` speaks to it,
:mod:`.pty` serves it.

- the axis state machine: ``requested_state`` 8 enters closed-loop control if the axis has no
  error and is calibrated (``motor.is_calibrated``, ``encoder.is_ready``; else INVALID_STATE
  and idle: the axis without a motor is never calibrated), 1 goes idle;
- in closed loop, torque mode: the setpoint passes the torque-mode velocity limiter
  (clamped to ``[(-vel_limit - v)·vel_gain, (vel_limit - v)·vel_gain]`` when the limiter is
  on, named per firmware), then ``torque_lim`` and ``current_lim·torque_constant``;
  ``|v| > vel_limit_tolerance·vel_limit`` with ``enable_overspeed_error`` sets the controller's
  OVERSPEED error and drops to idle;
- faults (overspeed, and those :meth:`Device.fault` injects: motor, encoder, e-stop, DC bus
  under-voltage) land in the registers as each firmware puts them: the failed part's own
  ``error``, its axis bit only in 0.5.1 and 0.5.5+, the DC bus in the axis error (0.5.1) or
  the system error (0.5.2+);
- the watchdog (``config.enable_watchdog``, ``config.watchdog_timeout``, the timeout taken at
  each feed as the firmware does): if not fed within it, axis error WATCHDOG_TIMER_EXPIRED and
  idle, torque zero, in every state. It is checked on the physics clock, so the plant sees zero
  torque from the expiry on (to one physics step), however late the emulator's thread runs.

The physics runs on its own fixed-step clock (``physics_rate``, 8 kHz like the firmware's control
loop) against wall time: before anything is answered the plant is brought up to now
(:meth:`Device.catch_up`), the motor torque held over each step. The simulated person pushes
while the axis is in closed loop (they take the handle when the machine is ready) and lets go
otherwise.
"""

from __future__ import annotations

import math
import struct
import time
from array import array
from collections import deque
from dataclasses import dataclass, field
from typing import Literal, get_args

from sessions.config import MachineConfig, SessionConfig, UserConfig
from sessions.machine.odrive.protocol import (
    AXIS_ERROR_CONTROLLER_FAILED,
    AXIS_ERROR_DC_BUS_UNDER_VOLTAGE,
    AXIS_ERROR_ENCODER_FAILED,
    AXIS_ERROR_ESTOP_REQUESTED,
    AXIS_ERROR_INVALID_STATE,
    AXIS_ERROR_MOTOR_FAILED,
    AXIS_ERROR_WATCHDOG_TIMER_EXPIRED,
    AXIS_STATE_CLOSED_LOOP_CONTROL,
    AXIS_STATE_IDLE,
    CONTROL_MODE_TORQUE_CONTROL,
    CONTROLLER_ERROR_OVERSPEED,
    ENCODER_ERROR_NO_RESPONSE,
    ERROR_REGISTERS,
    FIRMWARES,
    MOTOR_ERROR_CURRENT_LIMIT_VIOLATION,
    MOTOR_ERROR_SYSTEM_LEVEL,
    MOTOR_ERROR_UNKNOWN_TORQUE,
    SYSTEM_ERROR_DC_BUS_UNDER_VOLTAGE,
    Firmware,
)
from sessions.machine.spec import MachineSpec
from sessions.people import SimulatedUser
from sessions.plant import Plant

AXIS_COUNT = 2
FIRMWARE = (0, 5, 6)  # the default
HARDWARE = (3, 6, 56)
Build = Literal["release", "source"]
DeviceFault = Literal["motor", "encoder", "estop", "undervoltage", "overspeed"]
DEVICE_FAULTS: tuple[str, ...] = get_args(DeviceFault)
FACTORY = {"torque_constant": 0.04, "current_lim": 10.0}  # motor.hpp's defaults
SERIAL_NUMBER = 0x3061_3539_3235
TWO_PI = 2.0 * math.pi
# The rig's defaults are the machine's and the drive's: defined once, in their own models.
_MACHINE = MachineConfig()
_DRIVE = MachineSpec()


@dataclass(frozen=True)
class EmulatorConfig:
    """The emulated rig: who pushes, the handle's inertia, the drive train, and the drive:
    its firmware (version and build), its motor settings, whether the axis is calibrated, and
    a partial line left in its buffer by a host that died mid-line."""

    user: UserConfig = field(default_factory=UserConfig)
    inertia: float = _MACHINE.inertia  # J at the handle, kg·m²
    gear_ratio: float = _DRIVE.gear_ratio  # motor turns per handle turn
    direction: int = _DRIVE.direction  # +1: motor and handle turn the same way
    axis: int = _DRIVE.axis  # the axis the handle is on
    physics_rate: float = 8000.0  # Hz
    seed: int = 1
    initial_turns: float = 0.0  # encoder position at power-up, motor turns
    current_lim: float = 60.0  # A (motor.config.current_lim of this rig; factory: 10)
    torque_constant: float = 0.35  # N·m/A: 21 N·m at the current limit (factory: 0.04)
    vbus: float = 24.0
    firmware: tuple[int, int, int] = FIRMWARE
    # "release": the released binaries (newlib-nano: 64-bit integers print "lu" and cannot be
    # written; 0.5.2-0.5.3 refuse enum writes); "source": a build with a full printf/scanf
    build: Build = "release"
    calibrated: bool = True  # the handle's axis: motor calibrated and encoder ready
    partial_line: str = ""  # bytes already in the device's line buffer at power-up

    def __post_init__(self) -> None:
        if self.direction not in (1, -1):
            raise ValueError("direction must be +1 or -1")
        if not (self.gear_ratio > 0 and self.inertia > 0 and self.physics_rate >= 100):
            raise ValueError("gear_ratio and inertia must be positive, physics_rate ≥ 100 Hz")
        if self.axis not in (0, 1):
            raise ValueError("axis must be 0 or 1")
        if tuple(self.firmware) not in FIRMWARES:
            known = ", ".join(f.name for f in FIRMWARES.values())
            raise ValueError(f"firmware must be one of {known}")
        if not (self.current_lim > 0 and self.torque_constant > 0):
            raise ValueError("current_lim and torque_constant must be positive")
        if self.build not in get_args(Build):
            raise ValueError("build must be 'release' or 'source'")

    @property
    def fw(self) -> Firmware:
        return FIRMWARES[tuple(self.firmware)]  # type: ignore[index]

    @classmethod
    def from_session(cls, cfg: SessionConfig, **kw: object) -> EmulatorConfig:
        """The person and handle of a scenario, on an emulated drive (``kw`` overrides)."""
        given = {"user": cfg.user, "inertia": cfg.machine.inertia, "seed": cfg.seed, **kw}
        return cls(**given)  # type: ignore[arg-type]

    @classmethod
    def for_rig(cls, drive: MachineSpec, machine: MachineConfig, **kw: object) -> EmulatorConfig:
        """The device a drive spec talks to: the same gear, direction and axis, the machine's
        inertia at the handle."""
        given: dict[str, object] = {
            "inertia": machine.inertia,
            "gear_ratio": drive.gear_ratio,
            "direction": drive.direction,
            "axis": drive.axis,
        }
        if drive.torque_constant is not None:  # the motor the drive spec expects
            given["torque_constant"] = drive.torque_constant
        return cls(**{**given, **kw})  # type: ignore[arg-type]


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
    motor_error: int
    encoder_error: int
    system_error: int
    watchdog_enabled: bool
    last_feed: float  # monotonic time of the last watchdog feed (-inf: never)
    watchdog_tripped_at: float | None  # physics time of the last expiry
    lines: int  # lines processed
    ignored_checksum: int  # lines ignored for a bad checksum
    engaged: bool  # the simulated person is pushing
    user_work: float  # true ∫ τ w dt of the person, J


# How a property is held and printed: f32 (``%f``), bool, u8 (``%u``), i32 and enum (``%d``),
# flags (an error register: uint32, ``%u`` or ``%ud``, written as an enum), flags64 (motor.error
# from 0.5.2: uint64), u64.
Kind = Literal["f32", "bool", "u8", "i32", "enum", "flags", "flags64", "u64"]


@dataclass
class Prop:
    kind: Kind
    value: float | int | bool
    writable: bool = True


def axis_props(rig: EmulatorConfig, motor: bool) -> dict[str, Prop]:
    """One axis' properties; ``motor``: the handle's motor is on this axis."""
    fw = rig.fw
    ready = motor and rig.calibrated
    return {
        "error": Prop("flags", 0),
        "current_state": Prop("enum", AXIS_STATE_IDLE, writable=False),
        "requested_state": Prop("enum", 0),
        "config.enable_watchdog": Prop("bool", False),
        "config.watchdog_timeout": Prop("f32", 0.0),
        "controller.error": Prop("flags", 0),
        "controller.input_torque": Prop("f32", 0.0),
        "controller.config.control_mode": Prop("enum", 3),
        "controller.config.input_mode": Prop("enum", 1),
        "controller.config.vel_limit": Prop("f32", 2.0),
        "controller.config.vel_gain": Prop("f32", 1.0 / 6.0),
        "controller.config.vel_limit_tolerance": Prop("f32", 1.2),
        fw.limiter: Prop("bool", True),
        "controller.config.enable_overspeed_error": Prop("bool", True),
        "motor.error": Prop("flags64" if fw.motor_error_64 else "flags", 0),
        "motor.is_calibrated": Prop("bool", ready, writable=False),
        "motor.config.torque_lim": Prop("f32", math.inf),
        "motor.config.current_lim": Prop("f32", rig.current_lim),
        "motor.config.current_lim_margin": Prop("f32", 8.0),
        "motor.config.torque_constant": Prop("f32", rig.torque_constant),
        "encoder.error": Prop("flags", 0),
        "encoder.is_ready": Prop("bool", ready, writable=False),
        "encoder.pos_estimate": Prop("f32", 0.0, writable=False),
        "encoder.vel_estimate": Prop("f32", 0.0, writable=False),
    }


class Axis:
    """One axis' property tree, with direct references to the properties the physics reads."""

    __slots__ = (
        "props", "last_feed", "feed_timeout", "tripped_at", "applied", "wd_enable",
        "wd_timeout", "state", "error", "ctrl_error", "motor_error", "encoder_error",
        "input_torque", "control_mode", "vel_limit", "vel_gain", "vel_tolerance",
        "torque_mode_vel_limit", "overspeed_error", "torque_lim", "current_lim",
        "torque_constant",
    )  # fmt: skip

    def __init__(self, rig: EmulatorConfig, motor: bool) -> None:
        p = self.props = axis_props(rig, motor)
        self.last_feed = -math.inf
        self.feed_timeout = 0.0  # the watchdog_timeout taken at the last feed
        self.tripped_at: float | None = None
        self.applied = 0.0
        self.wd_enable = p["config.enable_watchdog"]
        self.wd_timeout = p["config.watchdog_timeout"]
        self.state = p["current_state"]
        self.error = p["error"]
        self.ctrl_error = p["controller.error"]
        self.motor_error = p["motor.error"]
        self.encoder_error = p["encoder.error"]
        self.input_torque = p["controller.input_torque"]
        self.control_mode = p["controller.config.control_mode"]
        self.vel_limit = p["controller.config.vel_limit"]
        self.vel_gain = p["controller.config.vel_gain"]
        self.vel_tolerance = p["controller.config.vel_limit_tolerance"]
        self.torque_mode_vel_limit = p[rig.fw.limiter]
        self.overspeed_error = p["controller.config.enable_overspeed_error"]
        self.torque_lim = p["motor.config.torque_lim"]
        self.current_lim = p["motor.config.current_lim"]
        self.torque_constant = p["motor.config.torque_constant"]

    def get(self, name: str) -> float:
        return self.props[name].value  # type: ignore[return-value]

    def set(self, name: str, value: float | int | bool) -> None:
        self.props[name].value = value

    @property
    def faulted(self) -> bool:
        """Any error register is non-zero."""
        return any(self.props[n].value for n in ERROR_REGISTERS)


class Device:
    """One emulated ODrive: two axes (the handle on ``rig.axis``), its physics clock and what
    it noted (closed loop, watchdog expiry, the person taking the handle…)."""

    def __init__(self, rig: EmulatorConfig | None = None) -> None:
        self.rig = r = rig or EmulatorConfig()
        self.h = 1.0 / r.physics_rate
        self.turns_per_rad = r.direction * r.gear_ratio / TWO_PI  # handle rad → motor turns
        self.handle_per_motor_torque = r.direction * r.gear_ratio
        self.torque_log = TorqueLog()
        self.log: deque[tuple[float, str]] = deque(maxlen=10_000)
        self.log_total = 0
        self.fw = r.fw
        self.axes = [Axis(r, i == r.axis) for i in range(AXIS_COUNT)]
        self.rig_axis = self.axes[r.axis]
        self.system_error = 0  # the root ``error`` (0.5.2+)
        self.plant = Plant(r.inertia)
        self.user = SimulatedUser(r.user, self.h, r.seed)
        self.engaged = False
        self.lines = 0  # lines processed
        self.ignored_checksum = 0  # lines ignored for a bad checksum
        self.t0 = time.monotonic()
        self.k = 0  # physics steps since t0

    # -- the physics clock ----------------------------------------------------------------------
    @property
    def t_phys(self) -> float:
        return self.t0 + self.k * self.h

    def catch_up(self, now: float) -> None:
        """Bring the physics up to monotonic time ``now``."""
        n = int((now - self.t0) / self.h)
        while self.k < n:
            self._step()

    def _step(self) -> None:
        """One physics step starting at t_phys: checks, torque, plant."""
        ts = self.t_phys
        h = self.h
        for ax in self.axes:
            if ax.wd_enable.value and ts - ax.last_feed > ax.feed_timeout:
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
                self.fault("overspeed", ts)
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
            self.note(ts, "person takes the handle" if closed else "person lets go")
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

    def note(self, at: float, what: str) -> None:
        self.log.append((at, what))
        self.log_total += 1

    def _trip(self, ax: Axis, bits: int, at: float, why: str) -> None:
        ax.error.value = int(ax.error.value) | bits
        ax.state.value = AXIS_STATE_IDLE
        ax.applied = 0.0
        self.note(at, why)

    def fault(self, kind: DeviceFault, at: float) -> None:
        """A fault of the handle's axis, in the registers as this firmware puts it; the axis
        drops to idle (torque zero)."""
        ax, fw = self.rig_axis, self.fw
        bits = 0  # the axis bit naming the failed part: 0.5.1 and 0.5.5+ only
        if kind == "motor":
            ax.motor_error.value |= MOTOR_ERROR_CURRENT_LIMIT_VIOLATION  # type: ignore[operator]
            bits = AXIS_ERROR_MOTOR_FAILED
        elif kind == "encoder":
            ax.encoder_error.value |= ENCODER_ERROR_NO_RESPONSE  # type: ignore[operator]
            bits = AXIS_ERROR_ENCODER_FAILED
        elif kind == "overspeed":
            ax.ctrl_error.value |= CONTROLLER_ERROR_OVERSPEED  # type: ignore[operator]
            bits = AXIS_ERROR_CONTROLLER_FAILED
            if not fw.axis_failure_bits:  # 0.5.2-0.5.4: the torque goes missing, the motor
                ax.motor_error.value |= MOTOR_ERROR_UNKNOWN_TORQUE  # type: ignore[operator]
        elif kind == "estop":
            self._trip(ax, AXIS_ERROR_ESTOP_REQUESTED, at, "estop requested")
            return
        elif kind == "undervoltage":
            if fw.system_error:  # 0.5.2+: the system's error, the motor's "system level"
                self.system_error |= SYSTEM_ERROR_DC_BUS_UNDER_VOLTAGE
                ax.motor_error.value |= MOTOR_ERROR_SYSTEM_LEVEL  # type: ignore[operator]
                bits = AXIS_ERROR_MOTOR_FAILED
            else:
                self._trip(ax, AXIS_ERROR_DC_BUS_UNDER_VOLTAGE, at, "DC bus under voltage")
                return
        else:
            raise ValueError(f"unknown device fault {kind!r}; one of {', '.join(DEVICE_FAULTS)}")
        self._trip(ax, bits if fw.axis_failure_bits else 0, at, f"{kind} fault")

    # -- what the commands do ----------------------------------------------------------------------
    def motor_pos(self) -> float:
        return self.plant.q * self.turns_per_rad + self.rig.initial_turns

    def motor_vel(self) -> float:
        return self.plant.w * self.turns_per_rad

    def feedback(self, ax: Axis) -> tuple[float, float]:
        """(pos turns, vel turns/s) as the firmware's float32 estimates; 0 on the axis
        without a motor, and (from 0.5.2) 0 without a valid estimate (encoder failed)."""
        if ax is not self.rig_axis or (self.fw.has_sc and ax.encoder_error.value):
            return 0.0, 0.0
        return f32(self.motor_pos()), f32(self.motor_vel())

    def set_torque(self, ax: Axis, torque: float, now: float) -> None:
        """``c``: torque control, this setpoint (motor N·m), the watchdog fed."""
        ax.set("controller.config.control_mode", CONTROL_MODE_TORQUE_CONTROL)
        ax.set("controller.input_torque", torque)
        self.feed(ax, now)
        if ax is self.rig_axis:
            self.torque_log.append(now, torque)

    def feed(self, ax: Axis, now: float) -> None:
        """Feed the watchdog: its timeout is loaded now (a new one applies from the next feed)."""
        ax.last_feed = now
        ax.feed_timeout = float(ax.wd_timeout.value)

    def find(self, path: str) -> tuple[Axis | None, str] | None:
        """The property ``path`` names: (axis, name below it), (None, root name) or None."""
        for i, ax in enumerate(self.axes):
            prefix = f"axis{i}."
            if path.startswith(prefix) and path[len(prefix) :] in ax.props:
                return ax, path[len(prefix) :]
        if path in ROOT_PROPS or (path == "error" and self.fw.system_error):
            return None, path
        return None

    def get(self, ax: Axis | None, name: str) -> float | int | bool:
        if ax is None:
            return self._root(name)
        if ax is self.rig_axis and name == "encoder.pos_estimate":
            return f32(self.motor_pos())
        if ax is self.rig_axis and name == "encoder.vel_estimate":
            return f32(self.motor_vel())
        return ax.props[name].value

    def _root(self, name: str) -> float | int:
        fw = self.fw.version
        return {
            "fw_version_major": fw[0],
            "fw_version_minor": fw[1],
            "fw_version_revision": fw[2],
            "hw_version_major": HARDWARE[0],
            "hw_version_minor": HARDWARE[1],
            "hw_version_variant": HARDWARE[2],
            "vbus_voltage": self.rig.vbus,
            "serial_number": SERIAL_NUMBER,
            "error": self.system_error,
        }[name]

    def kind(self, ax: Axis | None, name: str) -> Kind:
        if ax is None:
            return ROOT_KINDS[name]
        return ax.props[name].kind

    def writable(self, ax: Axis | None, name: str) -> Prop | None:
        """The property if it may be written (root properties and estimates may not)."""
        if ax is None or not ax.props[name].writable:
            return None
        return ax.props[name]

    def write(self, ax: Axis, name: str, value: float | int | bool, now: float) -> None:
        ax.set(name, value)
        if name == "requested_state":
            self._request_state(ax, int(value), now)

    def _request_state(self, ax: Axis, state: int, now: float) -> None:
        ax.error.value = int(ax.error.value) & ~AXIS_ERROR_INVALID_STATE  # cleared per request
        if state == AXIS_STATE_CLOSED_LOOP_CONTROL:
            if ax.faulted:
                self.note(now, "closed loop refused (errors latched)")
            elif not (ax.get("motor.is_calibrated") and ax.get("encoder.is_ready")):
                self._trip(ax, AXIS_ERROR_INVALID_STATE, now, "closed loop refused: not calibrated")
            else:
                ax.set("current_state", AXIS_STATE_CLOSED_LOOP_CONTROL)
                self.feed(ax, now)  # entering closed loop feeds the watchdog
                self.note(now, "closed loop")
        elif state == AXIS_STATE_IDLE:
            ax.set("current_state", AXIS_STATE_IDLE)
            self.note(now, "idle")

    def clear_errors(self) -> None:
        """``sc``: every axis' errors and the system's."""
        for ax in self.axes:
            for name in ERROR_REGISTERS:
                ax.set(name, 0)
        self.system_error = 0

    def reset_config(self, now: float, *, reboot: bool) -> None:
        """``se`` (erase the configuration) and ``sr`` (reboot): both axes as at power-up."""
        self.axes = [Axis(self.rig, i == self.rig.axis) for i in range(AXIS_COUNT)]
        self.rig_axis = self.axes[self.rig.axis]
        if reboot:
            self.note(now, "reboot")

    # -- observation ---------------------------------------------------------------------------
    def snapshot(self, now: float) -> EmulatorSnapshot:
        """The state at monotonic time ``now`` (the physics brought up to it)."""
        self.catch_up(now)
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
            motor_error=int(ax.get("motor.error")),
            encoder_error=int(ax.get("encoder.error")),
            system_error=self.system_error,
            watchdog_enabled=bool(ax.get("config.enable_watchdog")),
            last_feed=ax.last_feed,
            watchdog_tripped_at=ax.tripped_at,
            lines=self.lines,
            ignored_checksum=self.ignored_checksum,
            engaged=self.engaged,
            user_work=self.plant.user_work,
        )


def f32(x: float) -> float:
    """``x`` as the firmware holds it (float32); too large: ±inf."""
    try:
        return struct.unpack("f", struct.pack("f", x))[0]
    except OverflowError:
        return math.copysign(math.inf, x)


class TorqueLog:
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


class _Nobody:
    """Nobody on the handle: zero torque."""

    @staticmethod
    def torque(q: float, w: float) -> float:
        return 0.0


_NOBODY = _Nobody()
ROOT_KINDS: dict[str, Kind] = {
    "fw_version_major": "u8",
    "fw_version_minor": "u8",
    "fw_version_revision": "u8",
    "hw_version_major": "u8",
    "hw_version_minor": "u8",
    "hw_version_variant": "u8",
    "vbus_voltage": "f32",
    "serial_number": "u64",
    "error": "flags",  # 0.5.2+
}
ROOT_PROPS = frozenset(ROOT_KINDS) - {"error"}
