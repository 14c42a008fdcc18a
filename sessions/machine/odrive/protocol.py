"""Facts of the ODrive ASCII protocol (firmware 0.5.x, ODrive v3.x) used by both ends here.

Checked against the 0.5.x firmware's ``ascii_protocol.cpp`` and the public docs:

- A line is ``command *CK ; comment`` ending in ``\\n``, ``\\r`` or ``!``; at most 256
  characters (a longer one is dropped up to its end). ``CK`` (optional) is the XOR of every
  byte before ``*``, in decimal; a line with a wrong checksum is ignored without a reply. If a
  checksum was sent, the reply carries one: ``reply*CK\\r\\n`` over the reply's bytes.
- Replies end in ``\\r\\n``; commands are not echoed. Commands that succeed silently (``c``,
  ``u``, ``w``, ``sc``…) send nothing. An empty line answers ``unknown command``.
- ``c <axis> <torque>``: torque setpoint in N·m (motor side); also switches the controller to
  torque control and feeds the axis watchdog. ``u <axis>``: feeds the watchdog only.
  ``f <axis>``: replies ``<pos> <vel>`` (turns, turns/s, printf ``%f``).
  ``r <path>`` replies the value, ``w <path> <value>`` writes it. ``sc``: clear errors.
- Errors: ``invalid command format``, ``invalid motor N``, ``invalid property``,
  ``not implemented``, ``unknown command``.
"""

from __future__ import annotations

MAX_LINE = 256
LINE_ENDS = b"\r\n!"

# axis states
AXIS_STATE_IDLE = 1
AXIS_STATE_CLOSED_LOOP_CONTROL = 8
# controller modes
CONTROL_MODE_TORQUE_CONTROL = 1
INPUT_MODE_PASSTHROUGH = 1
# axis.error bits (0.5.x)
AXIS_ERROR_INVALID_STATE = 0x1
AXIS_ERROR_MOTOR_FAILED = 0x40
AXIS_ERROR_CONTROLLER_FAILED = 0x200
AXIS_ERROR_WATCHDOG_TIMER_EXPIRED = 0x800
# controller.error bits (0.5.x)
CONTROLLER_ERROR_OVERSPEED = 0x1

AXIS_ERRORS: dict[int, str] = {
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


def checksum(data: bytes) -> int:
    """XOR of the bytes: the protocol's optional line checksum."""
    ck = 0
    for b in data:
        ck ^= b
    return ck


def describe_axis_error(code: int) -> str:
    names = [name for bit, name in AXIS_ERRORS.items() if code & bit]
    unknown = code & ~sum(AXIS_ERRORS)
    if unknown:
        names.append(f"0x{unknown:x}")
    return f"axis error 0x{code:x} ({', '.join(names) or 'none'})"
