"""Facts of the ODrive ASCII protocol (firmware 0.5.1 … 0.5.6, ODrive v3.x) both ends share:
the framing, the error tables, and what differs from one firmware to the next.

Read in the firmware's ``ascii_protocol.cpp`` (0.5.1 and the 0.5.2+ ``AsciiProtocol`` class),
its ``odrive-interface.yaml`` error tables, ``fibre-cpp/protocol.hpp`` and the release notes:

- A line is ``command *CK ; comment`` ending in ``\\n``, ``\\r`` or ``!``; at most 256
  characters (a longer one is dropped up to its end). ``CK`` (optional) is the XOR of every
  byte before ``*``, in decimal, compared as a ``uint8_t``: a line with a wrong checksum is
  ignored without a reply, so ``*999`` (≥ 256) can never match. If a checksum was sent, the
  reply carries one: ``reply*CK\\r\\n``.
- Replies end in ``\\r\\n``; commands are not echoed. Commands that succeed silently (``c``,
  ``u``, ``w``, ``sc``…) send nothing. An empty line answers ``unknown command`` (from 0.5.2;
  0.5.1 says nothing).
- ``c <axis> <torque>``: torque setpoint in N·m (motor side); also switches the controller to
  torque control and feeds the axis watchdog. ``u <axis>``: feeds the watchdog only.
  ``f <axis>``: replies ``<pos> <vel>`` (turns, turns/s, printf ``%f``).
  ``r <path>`` replies the value (at most 9 characters: longer values are cut, silently),
  ``w <path> <value>`` writes it. ``sc`` (from 0.5.2): clear the errors of *both* axes and
  the system's, and re-arm the brake resistor.
- Errors: ``invalid command format``, ``invalid motor N``, ``invalid property``,
  ``not implemented``, ``unknown command``.
- A partial line left in the device's buffer (a host that died mid-line) is completed by the
  next bytes: a bare newline would *execute* it (a cut ``c 0 0.3`` commands 0.3 N·m).
  ``*999\\n`` turns whatever precedes it into a line whose checksum cannot match: dropped.
"""

from __future__ import annotations

from dataclasses import dataclass

MAX_LINE = 256
LINE_ENDS = b"\r\n!"
FLUSH_LINE = b"*999\n"  # ends a partial line so that it is dropped, never executed
R_REPLY_MAX = 9  # characters of an ``r`` reply (the firmware's 10-byte buffer)

# axis states
AXIS_STATE_IDLE = 1
AXIS_STATE_CLOSED_LOOP_CONTROL = 8
# controller modes
CONTROL_MODE_TORQUE_CONTROL = 1
INPUT_MODE_PASSTHROUGH = 1
# axis.error bits (every 0.5.x)
AXIS_ERROR_INVALID_STATE = 0x1
AXIS_ERROR_WATCHDOG_TIMER_EXPIRED = 0x800
AXIS_ERROR_ESTOP_REQUESTED = 0x4000
# axis.error bits that name the failed part (0.5.1, and again from 0.5.5)
AXIS_ERROR_MOTOR_FAILED = 0x40
AXIS_ERROR_ENCODER_FAILED = 0x100
AXIS_ERROR_CONTROLLER_FAILED = 0x200
# axis.error 0.5.1 only (0.5.2 moved the DC bus to the system error)
AXIS_ERROR_DC_BUS_UNDER_VOLTAGE = 0x2
# controller.error, encoder.error, motor.error, system error bits used by both ends
CONTROLLER_ERROR_OVERSPEED = 0x1
ENCODER_ERROR_NO_RESPONSE = 0x4
MOTOR_ERROR_CURRENT_LIMIT_VIOLATION = 0x1000
MOTOR_ERROR_SYSTEM_LEVEL = 0x100_0000  # 0.5.2+
MOTOR_ERROR_UNKNOWN_TORQUE = 0x1000_0000  # 0.5.2+
SYSTEM_ERROR_DC_BUS_UNDER_VOLTAGE = 0x2  # 0.5.2+

ERROR_REGISTERS = ("error", "controller.error", "encoder.error", "motor.error")  # of an axis

# -- error tables, per firmware ------------------------------------------------------------------
AXIS_ERRORS: dict[int, str] = {  # 0.5.2 … 0.5.6 (0x40, 0x80, 0x100, 0x200: 0.5.5+ only)
    0x1: "invalid state",
    0x40: "motor failed",
    0x80: "sensorless estimator failed",
    0x100: "encoder failed",
    0x200: "controller failed",
    0x800: "watchdog timer expired",
    0x1000: "min endstop pressed",
    0x2000: "max endstop pressed",
    0x4000: "estop requested",
    0x20000: "homing without endstop",
    0x40000: "over temperature",
    0x80000: "unknown position",
}
AXIS_ERRORS_051: dict[int, str] = {
    0x1: "invalid state",
    0x2: "DC bus under voltage",
    0x4: "DC bus over voltage",
    0x8: "current measurement timeout",
    0x10: "brake resistor disarmed",
    0x20: "motor disarmed",
    0x40: "motor failed",
    0x80: "sensorless estimator failed",
    0x100: "encoder failed",
    0x200: "controller failed",
    0x400: "position control during sensorless",
    0x800: "watchdog timer expired",
    0x1000: "min endstop pressed",
    0x2000: "max endstop pressed",
    0x4000: "estop requested",
    0x20000: "homing without endstop",
    0x40000: "over temperature",
}
_MOTOR_COMMON = {
    0x1: "phase resistance out of range",
    0x2: "phase inductance out of range",
    0x8: "DRV fault",
    0x10: "control deadline missed",
    0x80: "modulation magnitude",
    0x400: "current sense saturation",
    0x1000: "current limit violation",
}
MOTOR_ERRORS_051: dict[int, str] = {
    **_MOTOR_COMMON,
    0x4: "ADC failed",
    0x20: "not implemented motor type",
    0x40: "brake current out of range",
    0x100: "brake deadtime violation",
    0x200: "unexpected timer callback",
    0x2000: "brake duty cycle NaN",
    0x4000: "DC bus over regen current",
    0x8000: "DC bus over current",
}
MOTOR_ERRORS: dict[int, str] = {  # 0.5.2+: 64 bits
    **_MOTOR_COMMON,
    0x10000: "modulation is NaN",
    0x20000: "motor thermistor over temperature",
    0x40000: "FET thermistor over temperature",
    0x80000: "timer update missed",
    0x100000: "current measurement unavailable",
    0x200000: "controller failed",
    0x400000: "I bus out of range",
    0x800000: "brake resistor disarmed",
    0x1000000: "system level (see the system error)",
    0x2000000: "bad timing",
    0x4000000: "unknown phase estimate",
    0x8000000: "unknown phase velocity",
    0x10000000: "unknown torque",
    0x20000000: "unknown current command",
    0x40000000: "unknown current measurement",
    0x80000000: "unknown vbus voltage",
    0x100000000: "unknown voltage command",
    0x200000000: "unknown gains",
    0x400000000: "controller initializing",
    0x800000000: "unbalanced phases",
}
CONTROLLER_ERRORS: dict[int, str] = {
    0x1: "overspeed",
    0x2: "invalid input mode",
    0x4: "unstable gain",
    0x8: "invalid mirror axis",
    0x10: "invalid load encoder",
    0x20: "invalid estimate",
    0x40: "invalid circular range",  # 0.5.2+
    0x80: "spinout detected",  # 0.5.2+
}
ENCODER_ERRORS: dict[int, str] = {
    0x1: "unstable gain",
    0x2: "CPR/pole pairs mismatch",
    0x4: "no response",
    0x8: "unsupported encoder mode",
    0x10: "illegal hall state",
    0x20: "index not found yet",
    0x40: "absolute SPI timeout",
    0x80: "absolute SPI communication failure",
    0x100: "absolute SPI not ready",
    0x200: "hall not calibrated yet",  # 0.5.2+
}
SYSTEM_ERRORS: dict[int, str] = {  # 0.5.2+ (the root ``error``)
    0x1: "control iteration missed",
    0x2: "DC bus under voltage",
    0x4: "DC bus over voltage",
    0x8: "DC bus over regen current",
    0x10: "DC bus over current",
    0x20: "brake deadtime violation",
    0x40: "brake duty cycle NaN",
    0x80: "invalid brake resistance",
}


# -- what differs from one firmware to the next ---------------------------------------------------
LIMITER_OLD = "controller.config.enable_current_mode_vel_limit"  # 0.5.1 - 0.5.2
LIMITER = "controller.config.enable_torque_mode_vel_limit"  # 0.5.3+


@dataclass(frozen=True)
class Firmware:
    """One firmware version's behaviour on the ASCII line (what the emulator mimics and the
    backend handles). ``refused``: why the backend refuses it under the ``supported`` policy."""

    version: tuple[int, int, int]
    has_sc: bool  # ``sc`` exists (0.5.2+); 0.5.1 ignores it
    empty_line_reply: bool  # an empty line answers ``unknown command`` (0.5.2+)
    uint_suffix: bool  # unsigned ints print ``%ud``: ``0d`` (0.5.2 - 0.5.3)
    motor_error_64: bool  # motor.error is 64-bit (0.5.2+): ``lu`` on the release builds
    axis_failure_bits: bool  # a motor/encoder/controller fault sets its axis bit (0.5.1, 0.5.5+)
    system_error: bool  # the root ``error`` exists and holds the DC-bus faults (0.5.2+)
    enum_write_bug: bool  # release binaries answer enum writes ``not implemented`` (0.5.2-0.5.3)
    limiter: str  # the torque-mode velocity limiter's property
    refused: str | None = None

    @property
    def name(self) -> str:
        return ".".join(map(str, self.version))

    @property
    def axis_errors(self) -> dict[int, str]:
        return AXIS_ERRORS_051 if self.version <= (0, 5, 1) else AXIS_ERRORS

    @property
    def motor_errors(self) -> dict[int, str]:
        return MOTOR_ERRORS if self.motor_error_64 else MOTOR_ERRORS_051


_ENUM_BUG = (
    "its released binaries answer 'not implemented' to enum writes over ASCII (requested_state, "
    "control_mode: the 0.5.4 release notes' CI-compiler bug), so closed-loop control cannot be "
    "entered"
)


def _fw(rev: int, **kw: object) -> Firmware:
    new = rev >= 2
    base: dict[str, object] = {
        "version": (0, 5, rev),
        "has_sc": new,
        "empty_line_reply": new,
        "uint_suffix": rev in (2, 3),
        "motor_error_64": new,
        "axis_failure_bits": rev == 1 or rev >= 5,
        "system_error": new,
        "enum_write_bug": rev in (2, 3),
        "limiter": LIMITER_OLD if rev <= 2 else LIMITER,
        "refused": _ENUM_BUG if rev in (2, 3) else None,
    }
    return Firmware(**{**base, **kw})  # type: ignore[arg-type]


FIRMWARES: dict[tuple[int, int, int], Firmware] = {f.version: f for f in map(_fw, range(1, 7))}
SUPPORTED = tuple(v for v, f in FIRMWARES.items() if f.refused is None)
MIN_FIRMWARE = (0, 5, 4)  # the first without the 0.5.2-0.5.3 bugs; 0.5.1 works as well


def checksum(data: bytes) -> int:
    """XOR of the bytes: the protocol's optional line checksum."""
    ck = 0
    for b in data:
        ck ^= b
    return ck


def describe_bits(register: str, code: int, table: dict[int, str]) -> str:
    """``axis error 0x840 (motor failed, watchdog timer expired)``: every bit named."""
    names = [name for bit, name in table.items() if code & bit]
    unknown = code & ~sum(table)
    if unknown:
        names.append(f"unknown bits 0x{unknown:x}")
    return f"{register} error 0x{code:x} ({', '.join(names) or 'none'})"


def describe_axis_error(code: int, firmware: Firmware | None = None) -> str:
    table = firmware.axis_errors if firmware is not None else AXIS_ERRORS
    return describe_bits("axis", code, table)
