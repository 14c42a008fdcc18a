"""An ODrive (firmware 0.5.1, 0.5.4-0.5.6; v3.x boards) driven over its ASCII protocol.

Per cycle: ``read`` sends ``f <axis>`` and waits for ``<pos> <vel>`` (turns, turns/s at the
motor); ``write`` sends ``c <axis> <torque>`` (N·m at the motor), which also feeds the device
watchdog. Every ``health_period``, after its torque is out, one cycle also reads
``axis.error`` or (alternately) ``axis.current_state``, so a drive that dropped out of closed
loop (watchdog, overspeed, a motor or encoder fault, an e-stop) is a fault within two periods;
its reason then reads every error register (axis, motor, controller, encoder, system) and
names each bit, from the firmware's own tables. Exactly one request is in flight at a time
(:mod:`.link`).

Units: the loop works at the handle (rad, rad/s, N·m); the motor turns ``gear_ratio`` times per
handle turn, in the same or the opposite sense (``direction``)::

    motor turns = direction · gear_ratio · q / 2π        motor torque = direction · u / gear_ratio

Connect: ``*999`` first (a partial line left in the device by a host that died mid-line is
dropped, never executed), then the firmware version, accepted or refused
(:func:`.checks.accept_firmware`), and the name of its torque-mode velocity limiter.

Arm, in order: zero torque, idle, watchdog off, the axis' errors cleared (one register at a
time: ``sc`` would clear the other axis' too; it is used only where this firmware build cannot
write a register: 64-bit ``motor.error`` on the release builds), nothing left latched, the axis
calibrated, the drive's torque constant the motor's and its current limit above the session's
torque limit (:mod:`.checks`), then the limits written and read back, on the device itself so
they hold when this process is gone:

- ``motor.config.torque_lim`` = max_torque / gear_ratio;
- ``controller.config.vel_limit`` = velocity_margin × the machine's max velocity, with the
  torque-mode velocity limiter on and ``vel_gain`` chosen so that it removes torque only above
  the machine's max velocity (the limiter allows at most ``(vel_limit - |v|)·vel_gain``), the
  overspeed error on, tripping at ``vel_limit_tolerance`` × vel_limit;
- the axis watchdog (``watchdog_timeout``, ≤ 50 ms by default) fed by every ``c``: if the worker
  dies the drive drops to idle, torque zero, by itself.

Any timeout, garbled or short line, unexpected reply, error reply or axis error is a
:class:`MachineError`: zero torque and idle are sent at once and, when the line still answers
and the axis is idle, the watchdog is disabled (so the idle axis does not latch a watchdog
error on top of the real one); the fault is latched.
"""

from __future__ import annotations

import contextlib
import math
import time

from sessions.config import SessionConfig
from sessions.machine.base import Machine, MachineError
from sessions.machine.odrive import checks
from sessions.machine.odrive.link import AsciiLink, fmt
from sessions.machine.odrive.protocol import (
    AXIS_STATE_CLOSED_LOOP_CONTROL,
    AXIS_STATE_IDLE,
    CONTROL_MODE_TORQUE_CONTROL,
    ERROR_REGISTERS,
    INPUT_MODE_PASSTHROUGH,
    LIMITER,
    LIMITER_OLD,
    Firmware,
)
from sessions.machine.spec import MachineSpec


class OdriveMachine(Machine):
    kind = "odrive"
    has_torque_sensor = False
    free_running = True

    def __init__(self, spec: MachineSpec) -> None:
        super().__init__()
        if spec.device is None or spec.torque_constant is None:
            raise ValueError("the odrive machine needs a device path and a torque constant")
        self.spec = spec
        self.device = spec.device
        self.axis = spec.axis
        self.prefix = f"axis{spec.axis}."
        ratio = spec.direction * spec.gear_ratio
        self.rad_per_turn = 2.0 * math.pi / ratio  # motor turns → handle rad
        self.motor_per_handle_torque = 1.0 / ratio  # handle N·m → motor N·m
        self.link = AsciiLink(spec.device, spec.baudrate, spec.reply_timeout, spec.checksum)
        self.pos0 = 0.0
        self.health_every = 20
        self.countdown = 20
        self.health_turn = False
        self.firmware: tuple[int, int, int] | None = None
        self.fw: Firmware | None = None
        self.limiter = LIMITER
        self.notes: list[str] = []  # what arming found (trip current, how errors were cleared)
        self.f_request = self.link.encode(f"f {self.axis}")
        self.c_prefix = f"c {self.axis} "

    # -- helpers -------------------------------------------------------------------------
    def _set(self, path: str, value: float, *, tolerance: float = 1e-4) -> None:
        """Write a property and read it back: the write is confirmed (writes have no reply)."""
        refused, back = self.link.write(path, value, then=path)
        if refused is not None:
            raise MachineError(f"{path}: the device refused {fmt(value)} ({refused!r})")
        try:
            held = float(back)
        except ValueError:
            raise MachineError(f"garbled value for {path}: {back!r}") from None
        if not abs(held - value) <= tolerance * max(1.0, abs(value)):  # NaN-safe
            raise MachineError(f"{path}: wrote {fmt(value)}, the device holds {back}")

    def _request_state(self, state: int) -> None:
        path = self.prefix + "requested_state"
        refused, _ = self.link.write(path, state, then="fw_version_major")
        if refused is not None:
            assert self.fw is not None
            raise checks.enum_write_refused(self.fw)

    def _feed(self) -> None:
        self.link.send_text(f"u {self.axis}")

    def _fault(self, head: str) -> str:
        """``head`` and every error register's account of it."""
        assert self.fw is not None
        parts = checks.registers(self.link, self.prefix, self.fw, self.keepalive)
        return f"{head}: {checks.reasons(parts)}"

    # -- lifecycle hooks ---------------------------------------------------------------
    def _connect(self) -> None:
        link = self.link
        link.beat = self.keepalive
        link.open()
        major = _int(link.sync("r fw_version_major"), "fw_version_major")
        minor = link.read_int("fw_version_minor")
        revision = link.read_int("fw_version_revision")
        self.firmware = (major, minor, revision)
        self.fw = fw = checks.accept_firmware(self.firmware, self.spec.firmware_policy)
        link.uint_suffix = fw.uint_suffix
        if fw.enum_write_bug:  # a 0.5.2/0.5.3 build the operator vouches for: prove it
            self._request_state(AXIS_STATE_IDLE)
        self.limiter = self._limiter_name()

    def _limiter_name(self) -> str:
        """The torque-mode velocity limiter's property: renamed after 0.5.2."""
        for name in (LIMITER, LIMITER_OLD):
            text = self.link.ask(f"r {self.prefix}{name}", errors_ok=True)
            if not text.startswith("invalid property"):
                return name
        raise MachineError(
            f"ODrive firmware {self.fw.name if self.fw else '?'}: no torque-mode velocity "
            "limiter (enable_torque_mode_vel_limit or enable_current_mode_vel_limit)"
        )

    def _wait_state(self, want: int, limit: float) -> None:
        p = self.prefix
        deadline = time.monotonic() + limit
        while True:
            self.keepalive()
            self._feed()
            state = self.link.read_int(p + "current_state")
            if state == want:
                return
            entering = want == AXIS_STATE_CLOSED_LOOP_CONTROL
            if (entering and self.link.read_flags(p + "error")[0]) or time.monotonic() > deadline:
                raise MachineError(
                    self._fault(f"axis{self.axis} stayed in state {state} (wanted {want})")
                )
            time.sleep(0.002)

    def _clear_errors(self) -> None:
        """This axis' error registers cleared one by one (``sc`` only where this firmware
        build cannot write one: it clears the other axis' errors and the system's too)."""
        p, link, fw = self.prefix, self.link, self.fw
        assert fw is not None
        refused = [r for r in ERROR_REGISTERS if link.write(p + r, 0, then=p + r)[0] is not None]
        system = fw.system_error and link.read_flags("error")[0]
        if refused or system:
            if not fw.has_sc:
                raise MachineError(f"axis{self.axis}: the device refused to clear {refused}")
            link.send_text("sc")
            why = f"{', '.join(refused)} not writable here" if refused else "a system error"
            self.notes.append(
                f"errors cleared with sc ({why}): it clears axis{1 - self.axis}'s errors too"
            )
        left = checks.registers(link, p, fw, self.keepalive)
        if any("unreadable" not in part for part in left):
            raise MachineError("errors remain after clearing: " + checks.reasons(left))

    def _arm(self, cfg: SessionConfig) -> None:
        p, spec, link = self.prefix, self.spec, self.link
        assert spec.torque_constant is not None
        self.notes = []
        link.flush_input()
        link.send_text(f"c {self.axis} 0")
        self._request_state(AXIS_STATE_IDLE)
        self._wait_state(AXIS_STATE_IDLE, spec.closed_loop_timeout)
        self._set(p + "config.enable_watchdog", 0)
        self._clear_errors()
        checks.check_ready(link, p, self.axis)
        torque_lim = abs(cfg.machine.max_torque * self.motor_per_handle_torque)
        self.notes += checks.check_motor(link, p, spec.torque_constant, torque_lim, spec.gear_ratio)
        v_motor = cfg.machine.max_velocity * spec.gear_ratio / (2.0 * math.pi)  # turn/s
        vel_limit = spec.velocity_margin * v_motor
        vel_gain = torque_lim / (vel_limit - v_motor)
        self._set(p + "controller.config.control_mode", CONTROL_MODE_TORQUE_CONTROL)
        self._set(p + "controller.config.input_mode", INPUT_MODE_PASSTHROUGH)
        self._set(p + "controller.input_torque", 0.0)
        self._set(p + "motor.config.torque_lim", torque_lim)
        self._set(p + "controller.config.vel_limit", vel_limit)
        self._set(p + "controller.config.vel_gain", vel_gain)
        self._set(p + self.limiter, 1)
        self._set(p + "controller.config.enable_overspeed_error", 1)
        self._set(p + "controller.config.vel_limit_tolerance", spec.vel_limit_tolerance)
        self._set(p + "config.watchdog_timeout", spec.watchdog_timeout)
        self._feed()
        self._set(p + "config.enable_watchdog", 1)
        self._feed()
        self._request_state(AXIS_STATE_CLOSED_LOOP_CONTROL)
        self._wait_state(AXIS_STATE_CLOSED_LOOP_CONTROL, spec.closed_loop_timeout)
        self._feed()
        if link.read_flags(p + "error")[0]:
            raise MachineError(self._fault(f"axis{self.axis} faulted entering closed loop"))
        self.health_every = max(1, round(spec.health_period * cfg.rate))
        self.countdown = self.health_every
        self.pos0 = 0.0
        self.pos0 = self._feedback()[0]

    def _feedback(self) -> tuple[float, float]:
        link, req = self.link, self.f_request
        link.send(req)
        text = link.reply(req)
        parts = text.split()
        if len(parts) != 2:
            raise MachineError(f"short or garbled feedback {text!r}")
        try:
            pos, vel = float(parts[0]), float(parts[1])
        except ValueError:
            raise MachineError(f"garbled feedback {text!r}") from None
        if not (math.isfinite(pos) and math.isfinite(vel)):
            raise MachineError(f"non-finite feedback {text!r}")
        return pos, vel

    def _health(self) -> None:
        """One property a health period, alternating: the axis error bits (watchdog,
        overspeed, motor…), then the axis state (closed loop left for any other reason: on
        0.5.2-0.5.4 a motor or controller fault sets no axis bit)."""
        p = self.prefix
        self.health_turn = not self.health_turn
        if self.health_turn:
            if self.link.read_flags(p + "error")[0]:
                raise MachineError(self._fault(f"axis{self.axis} faulted"))
        else:
            state = self.link.read_int(p + "current_state")
            if state != AXIS_STATE_CLOSED_LOOP_CONTROL:
                raise MachineError(
                    self._fault(f"axis{self.axis} left closed-loop control (state {state})")
                )

    def _read(self) -> tuple[float, float, float]:
        pos, vel = self._feedback()
        k = self.rad_per_turn
        return (pos - self.pos0) * k, vel * k, math.nan

    def _write(self, u: float) -> None:
        self.link.send(self.link.encode(self.c_prefix + fmt(u * self.motor_per_handle_torque)))
        # after the torque is out, so the health check never delays the control path
        self.countdown -= 1
        if self.countdown <= 0:
            self.countdown = self.health_every
            self._health()

    def _zero(self) -> None:
        if self.link.is_open:
            self.link.send(self.link.encode(self.c_prefix + "0"))

    def _fail(self, reason: str) -> None:
        super()._fail(reason)
        with contextlib.suppress(Exception):  # best effort: the line may be what failed
            self._safe_idle()

    def _safe_idle(self) -> None:
        """The axis to idle, then (if the line answers and the axis is idle) the watchdog off:
        an enabled, unfed watchdog would latch its own error on the idle axis."""
        link = self.link
        if not link.is_open:
            return
        link.send_text(f"w {self.prefix}requested_state {AXIS_STATE_IDLE}")
        link.drain(quiet=link.timeout, limit=0.2)
        if link.read_int(self.prefix + "current_state") == AXIS_STATE_IDLE:
            self._set(self.prefix + "config.enable_watchdog", 0)

    def _disarm(self) -> None:
        p = self.prefix
        self._request_state(AXIS_STATE_IDLE)
        self._wait_state(AXIS_STATE_IDLE, self.spec.closed_loop_timeout)
        self._set(p + "config.enable_watchdog", 0)

    def _reset(self) -> None:
        self.link.close()
        self._connect()
        self.link.send_text(f"c {self.axis} 0")
        self._request_state(AXIS_STATE_IDLE)
        self._set(self.prefix + "config.enable_watchdog", 0)
        self._clear_errors()

    def _close(self) -> None:
        self.link.close()


def _int(text: str, what: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise MachineError(f"garbled value for {what}: {text!r}") from None
