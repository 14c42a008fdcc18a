"""An ODrive (firmware 0.5.x, v3.x boards) driven over its ASCII protocol with pyserial.

Per cycle: ``read`` sends ``f <axis>`` and waits for ``<pos> <vel>`` (turns, turns/s at the
motor); ``write`` sends ``c <axis> <torque>`` (N·m at the motor), which also feeds the device
watchdog. Every ``health_period``, after its torque is out, one cycle also reads
``axis.error`` or (alternately) ``axis.current_state``, so a drive that dropped out of closed
loop (watchdog, overspeed) is a fault within two periods. Exactly one request is in flight at
a time.

Units: the loop works at the handle (rad, rad/s, N·m); the motor turns ``gear_ratio`` times per
handle turn, in the same or the opposite sense (``direction``)::

    motor turns = direction · gear_ratio · q / 2π        motor torque = direction · u / gear_ratio

Safety, on the device itself (so it holds when this process is gone):
- ``motor.config.torque_lim`` = max_torque / gear_ratio;
- ``controller.config.vel_limit`` = velocity_margin × the machine's max velocity, with the
  torque-mode velocity limiter on and ``vel_gain`` chosen so that it removes torque only above
  the machine's max velocity (the limiter allows at most ``(vel_limit - |v|)·vel_gain``), and the
  overspeed error on;
- the axis watchdog (``watchdog_timeout``, ≤ 50 ms by default) fed by every ``c``: if the worker
  dies the drive drops to idle, torque zero, by itself.
Any timeout, garbled or short line, unexpected reply, error reply or axis error is a
:class:`MachineError`: zero torque and idle are sent best effort and the fault is latched.
Nothing here waits longer than ``timeout`` for a byte.
"""

from __future__ import annotations

import contextlib
import math
import select
import time

import serial

from sessions.config import SessionConfig
from sessions.machine.base import Machine, MachineError
from sessions.machine.odrive.protocol import (
    AXIS_STATE_CLOSED_LOOP_CONTROL,
    AXIS_STATE_IDLE,
    CONTROL_MODE_TORQUE_CONTROL,
    INPUT_MODE_PASSTHROUGH,
    MAX_LINE,
    checksum,
    describe_axis_error,
)
from sessions.machine.spec import MachineSpec

ERROR_REPLIES = (
    "invalid command format",
    "invalid motor",
    "invalid property",
    "not implemented",
    "unknown command",
)
SUPPORTED_FIRMWARE = (0, 5)


class OdriveMachine(Machine):
    kind = "odrive"
    has_torque_sensor = False

    def __init__(self, spec: MachineSpec) -> None:
        super().__init__()
        if spec.device is None:
            raise ValueError("the odrive machine needs a device path")
        self.spec = spec
        self.device = spec.device
        self.axis = spec.axis
        self.prefix = f"axis{spec.axis}."
        ratio = spec.direction * spec.gear_ratio
        self.rad_per_turn = 2.0 * math.pi / ratio  # motor turns → handle rad
        self.motor_per_handle_torque = 1.0 / ratio  # handle N·m → motor N·m
        self.timeout = spec.reply_timeout
        self.use_checksum = spec.checksum
        self.ser: serial.Serial | None = None
        self.fd = -1
        self.buf = bytearray()
        self.pos0 = 0.0
        self.health_every = 20
        self.countdown = 20
        self.health_turn = False
        self.firmware: tuple[int, int, int] | None = None
        self.f_request = self._encode(f"f {self.axis}")
        self.c_prefix = f"c {self.axis} "

    # -- framing -----------------------------------------------------------------------
    def _encode(self, text: str) -> bytes:
        data = text.encode("ascii")
        if self.use_checksum:
            data += b" "
            data += b"*%d" % checksum(data)
        return data + b"\n"

    def _send(self, data: bytes) -> None:
        ser = self.ser
        if ser is None:
            raise MachineError("serial port not open")
        try:
            n = ser.write(data)
        except serial.SerialTimeoutException:
            raise MachineError(f"write timed out after {self.timeout * 1e3:.0f} ms") from None
        except (serial.SerialException, OSError) as exc:
            raise MachineError(f"serial write failed: {exc}") from None
        if n != len(data):
            raise MachineError("serial write incomplete")

    def _reply(self, request: bytes) -> str:
        """The one reply line to ``request`` (already sent), checked; nothing else may follow."""
        return self._check(self._line(request), request)

    def _line(self, request: bytes) -> bytes:
        """Wait (at most ``timeout``) for the reply's line; return it without its ``\n``."""
        buf = self.buf
        deadline = time.monotonic() + self.timeout
        ser = self.ser
        assert ser is not None
        while True:
            i = buf.find(b"\n")
            if i >= 0:
                break
            if len(buf) > MAX_LINE:
                raise MachineError(f"garbled reply to {_show(request)}: {_show(bytes(buf[:40]))}…")
            remaining = deadline - time.monotonic()
            if remaining <= 0.0 and not self._take_available(buf):
                what = f"partial line {_show(bytes(buf))}" if buf else "no reply"
                raise MachineError(
                    f"timeout: {what} to {_show(request)} within {self.timeout * 1e3:.0f} ms"
                )
            if remaining <= 0.0:
                continue  # the last look found bytes: parse them
            try:
                ready, _, _ = select.select((self.fd,), (), (), remaining)
                if ready:
                    chunk = ser.read(4096)
                    if chunk:
                        buf += chunk
            except (serial.SerialException, OSError) as exc:
                raise MachineError(f"serial read failed: {exc}") from None
        line = bytes(buf[:i])
        del buf[: i + 1]
        if buf:
            extra = bytes(buf)
            buf.clear()
            raise MachineError(
                f"unexpected data after the reply to {_show(request)}: {_show(extra)}"
            )
        return line

    def _check(self, line: bytes, request: bytes) -> str:
        """A reply line's text: framing, checksum, encoding and error replies checked."""
        if not line.endswith(b"\r"):
            raise MachineError(f"garbled reply to {_show(request)}: {_show(line)}")
        line = line[:-1]
        if self.use_checksum:
            star = line.rfind(b"*")
            if star < 0:
                raise MachineError(
                    f"garbled reply (no checksum) to {_show(request)}: " + _show(line)
                )
            body, ck = line[:star], line[star + 1 :]
            if not ck.isdigit() or int(ck) != checksum(body):
                raise MachineError(
                    f"garbled reply (bad checksum) to {_show(request)}: " + _show(line)
                )
            line = body
        try:
            text = line.decode("ascii")
        except UnicodeDecodeError:
            raise MachineError(f"garbled reply to {_show(request)}: {_show(line)}") from None
        if not text.isprintable():
            raise MachineError(f"garbled reply to {_show(request)}: {_show(line)}")
        if text.startswith(ERROR_REPLIES):
            raise MachineError(f"device replied {text!r} to {_show(request)}")
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

    def _ask(self, command: str) -> str:
        req = self._encode(command)
        self._send(req)
        return self._reply(req)

    def _read_number(self, path: str) -> float:
        text = self._ask(f"r {path}")
        try:
            value = float(text)
        except ValueError:
            raise MachineError(f"garbled value for {path}: {text!r}") from None
        if not math.isfinite(value):
            raise MachineError(f"non-finite value for {path}: {text!r}")
        return value

    def _set(self, path: str, value: float, *, tolerance: float = 1e-4) -> None:
        """Write a property and read it back: the write is confirmed (writes have no reply)."""
        self._send(self._encode(f"w {path} {_fmt(value)}"))
        back = self._read_number(path)
        if abs(back - value) > tolerance * max(1.0, abs(value)):
            raise MachineError(f"{path}: wrote {value!r}, device holds {back!r}")

    def _feed(self) -> None:
        self._send(self._encode(f"u {self.axis}"))

    # -- lifecycle hooks ---------------------------------------------------------------
    def _open(self) -> None:
        try:
            self.ser = serial.Serial(
                self.device,
                self.spec.baudrate,
                timeout=0,
                write_timeout=self.timeout,
                exclusive=True,
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise MachineError(f"cannot open {self.device}: {exc}") from None
        self.fd = self.ser.fileno()
        self.ser.reset_input_buffer()
        self.buf.clear()

    def _connect(self) -> None:
        self._open()
        major = int(self._read_number("fw_version_major"))
        minor = int(self._read_number("fw_version_minor"))
        revision = int(self._read_number("fw_version_revision"))
        self.firmware = (major, minor, revision)
        if (major, minor) != SUPPORTED_FIRMWARE:
            raise MachineError(
                f"unsupported ODrive firmware {major}.{minor}.{revision} (need 0.5.x)"
            )

    def _wait_state(self, want: int, limit: float) -> None:
        p = self.prefix
        deadline = time.monotonic() + limit
        while True:
            self.keepalive()
            self._feed()
            state = int(self._read_number(p + "current_state"))
            if state == want:
                return
            if time.monotonic() > deadline:
                err = int(self._read_number(p + "error"))
                raise MachineError(
                    f"axis{self.axis} stayed in state {state} (wanted {want}); "
                    + describe_axis_error(err)
                )
            time.sleep(0.002)

    def _arm(self, cfg: SessionConfig) -> None:
        p, spec = self.prefix, self.spec
        self._flush_input()
        self._send(self._encode(f"c {self.axis} 0"))
        self._send(self._encode(f"w {p}requested_state {AXIS_STATE_IDLE}"))
        self._wait_state(AXIS_STATE_IDLE, spec.closed_loop_timeout)
        self._set(p + "config.enable_watchdog", 0)
        self._send(self._encode("sc"))
        err = int(self._read_number(p + "error"))
        if err:
            raise MachineError("errors remain after clearing: " + describe_axis_error(err))
        torque_lim = abs(cfg.machine.max_torque * self.motor_per_handle_torque)
        v_motor = cfg.machine.max_velocity * spec.gear_ratio / (2.0 * math.pi)  # turn/s
        vel_limit = spec.velocity_margin * v_motor
        vel_gain = torque_lim / (vel_limit - v_motor)
        self._set(p + "controller.config.control_mode", CONTROL_MODE_TORQUE_CONTROL)
        self._set(p + "controller.config.input_mode", INPUT_MODE_PASSTHROUGH)
        self._set(p + "controller.input_torque", 0.0)
        self._set(p + "motor.config.torque_lim", torque_lim)
        self._set(p + "controller.config.vel_limit", vel_limit)
        self._set(p + "controller.config.vel_gain", vel_gain)
        self._set(p + "controller.config.enable_torque_mode_vel_limit", 1)
        self._set(p + "controller.config.enable_overspeed_error", 1)
        self._set(p + "config.watchdog_timeout", spec.watchdog_timeout)
        self._feed()
        self._set(p + "config.enable_watchdog", 1)
        self._feed()
        self._send(self._encode(f"w {p}requested_state {AXIS_STATE_CLOSED_LOOP_CONTROL}"))
        self._wait_state(AXIS_STATE_CLOSED_LOOP_CONTROL, spec.closed_loop_timeout)
        self._feed()
        err = int(self._read_number(p + "error"))
        if err:
            raise MachineError(describe_axis_error(err))
        self.health_every = max(1, round(spec.health_period * cfg.rate))
        self.countdown = self.health_every
        self.pos0 = 0.0
        self.pos0 = self._feedback()[0]

    def _flush_input(self) -> None:
        if self.ser is not None:
            self.ser.reset_input_buffer()
        self.buf.clear()

    def _feedback(self) -> tuple[float, float]:
        req = self.f_request
        self._send(req)
        text = self._reply(req)
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
        overspeed, motor…), then the axis state (closed loop left for any other reason)."""
        p = self.prefix
        self.health_turn = not self.health_turn
        if self.health_turn:
            err = int(self._read_number(p + "error"))
            if err:
                raise MachineError(describe_axis_error(err))
        else:
            state = int(self._read_number(p + "current_state"))
            if state != AXIS_STATE_CLOSED_LOOP_CONTROL:
                raise MachineError(f"axis{self.axis} left closed-loop control (state {state})")

    def _read(self) -> tuple[float, float, float]:
        pos, vel = self._feedback()
        k = self.rad_per_turn
        return (pos - self.pos0) * k, vel * k, math.nan

    def _write(self, u: float) -> None:
        self._send(self._encode(self.c_prefix + _fmt(u * self.motor_per_handle_torque)))
        # after the torque is out, so the health check never delays the control path
        self.countdown -= 1
        if self.countdown <= 0:
            self.countdown = self.health_every
            self._health()

    def _zero(self) -> None:
        if self.ser is not None and self.ser.is_open:
            self.ser.write(self._encode(self.c_prefix + "0"))

    def _fail(self, reason: str) -> None:
        super()._fail(reason)
        try:  # the axis to idle as well; the watchdog would do it anyway
            if self.ser is not None and self.ser.is_open:
                self.ser.write(self._encode(f"w {self.prefix}requested_state {AXIS_STATE_IDLE}"))
        except Exception:
            pass

    def _disarm(self) -> None:
        p = self.prefix
        self._send(self._encode(f"w {p}requested_state {AXIS_STATE_IDLE}"))
        self._wait_state(AXIS_STATE_IDLE, self.spec.closed_loop_timeout)
        self._set(p + "config.enable_watchdog", 0)

    def _reset(self) -> None:
        self._close()
        self._open()
        self._send(self._encode(f"c {self.axis} 0"))
        self._send(self._encode(f"w {self.prefix}requested_state {AXIS_STATE_IDLE}"))
        self._set(self.prefix + "config.enable_watchdog", 0)
        self._send(self._encode("sc"))
        err = int(self._read_number(self.prefix + "error"))
        if err:
            raise MachineError("errors remain after clearing: " + describe_axis_error(err))

    def _close(self) -> None:
        ser, self.ser = self.ser, None
        self.fd = -1
        self.buf.clear()
        if ser is not None:
            with contextlib.suppress(Exception):
                ser.close()


def _fmt(value: float) -> str:
    if value == int(value) and abs(value) < 1e9:
        return str(int(value))
    return f"{value:.7g}"


def _show(data: bytes) -> str:
    text = repr(data[:60])
    return text + ("…" if len(data) > 60 else "")
