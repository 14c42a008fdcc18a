"""What the backend checks on the drive before it lets a motor move, and how it reads a fault.

- **Firmware** (:func:`accept_firmware`): 0.5.1 and 0.5.4-0.5.6 are supported, each with its
  own behaviour (:data:`sessions.machine.odrive.protocol.FIRMWARES`); 0.5.2 and 0.5.3 are
  refused (their released binaries cannot enter closed loop over ASCII) unless the operator
  vouches for a build of their own (policy ``probe``: a harmless enum write must then work).
- **Readiness** (:func:`check_ready`): the axis' motor calibrated and encoder ready, else the
  firmware would refuse closed loop (INVALID_STATE) — the wrong axis has neither.
- **Settings that scale or bound the torque** (:func:`check_motor`): the drive turns N·m into
  amperes with ``motor.config.torque_constant`` (it must be the motor's: the machine's setting),
  and clips at ``current_lim·torque_constant``, which must not be below the session's torque
  limit (the drive would cut commands silently, and could not brake a person pushing harder).
- **Reasons of a fault** (:func:`registers`): every error register, each bit named from the
  firmware's own table: the axis', the motor's, the controller's, the encoder's, the system's.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from sessions.machine.base import MachineError
from sessions.machine.odrive.link import AsciiLink
from sessions.machine.odrive.protocol import (
    CONTROLLER_ERRORS,
    ENCODER_ERRORS,
    FIRMWARES,
    MIN_FIRMWARE,
    SUPPORTED,
    SYSTEM_ERRORS,
    Firmware,
    describe_bits,
)

TORQUE_CONSTANT_TOLERANCE = 0.02  # relative: the drive's Kt within 2 % of the machine's


def _names(versions: tuple[tuple[int, int, int], ...]) -> str:
    return ", ".join(".".join(map(str, v)) for v in versions)


def accept_firmware(version: tuple[int, int, int], policy: str) -> Firmware:
    """The firmware's behaviour, or a MachineError naming what is supported."""
    name = ".".join(map(str, version))
    fw = FIRMWARES.get(version)
    if fw is None:
        raise MachineError(
            f"unsupported ODrive firmware {name}: supported are {_names(SUPPORTED)} "
            f"(ODrive v3.x, ASCII protocol)"
        )
    if fw.refused is not None and policy != "probe":
        raise MachineError(
            f"ODrive firmware {name} is refused: {fw.refused}; update to "
            f"{'.'.join(map(str, MIN_FIRMWARE))} or later (firmware_policy = 'probe' accepts "
            "a build of your own that has not the bug)"
        )
    return fw


def enum_write_refused(fw: Firmware) -> MachineError:
    return MachineError(
        f"ODrive firmware {fw.name}: this build answers 'not implemented' to enum writes "
        f"(the bug of the released {fw.name} binaries, fixed in 0.5.4); update the firmware"
    )


def check_ready(link: AsciiLink, prefix: str, axis: int) -> None:
    """The axis can enter closed loop: motor calibrated, encoder ready (else: why not)."""
    missing = []
    if not link.read_int(prefix + "motor.is_calibrated"):
        missing.append("the motor is not calibrated (motor.is_calibrated = 0)")
    if not link.read_int(prefix + "encoder.is_ready"):
        missing.append("the encoder is not ready (encoder.is_ready = 0)")
    if missing:
        raise MachineError(
            f"axis{axis} cannot enter closed-loop control: {'; '.join(missing)}. Is the "
            f"handle's motor on axis{axis} (setting axis)? If so, calibrate it "
            "(odrivetool: requested_state = AXIS_STATE_FULL_CALIBRATION_SEQUENCE) and save"
        )


def check_motor(
    link: AsciiLink, prefix: str, expected_kt: float, torque_lim: float, gear: float
) -> list[str]:
    """The drive's torque constant is the motor's, and its current limit allows the session's
    torque limit (``torque_lim``, motor side). Returns notes (the trip margin read)."""
    kt = link.read_float(prefix + "motor.config.torque_constant")
    if not (math.isfinite(kt) and kt > 0):
        raise MachineError(f"motor.config.torque_constant is {kt!r}: not a torque constant")
    if abs(kt - expected_kt) > TORQUE_CONSTANT_TOLERANCE * expected_kt:
        raise MachineError(
            f"motor.config.torque_constant is {kt:g} N·m/A but this machine's motor has "
            f"{expected_kt:g} N·m/A (setting torque_constant): every torque, and the drive's "
            f"torque limit, would be off by ×{expected_kt / kt:.3g}. Set the drive's to the "
            "motor's (8.27/Kv), or correct the setting"
        )
    i_lim = link.read_float(prefix + "motor.config.current_lim")
    if not (math.isfinite(i_lim) and i_lim > 0):
        raise MachineError(f"motor.config.current_lim is {i_lim!r} A: no current limit")
    most = i_lim * kt
    if most < torque_lim * (1.0 - 1e-6):
        raise MachineError(
            f"motor.config.current_lim {i_lim:g} A × torque_constant {kt:g} N·m/A = "
            f"{most:.3g} N·m at the motor ({most * gear:.3g} N·m at the handle) is below the "
            f"session's torque limit ({torque_lim:.3g} N·m at the motor): the drive would cut "
            "larger commands without a word, and could not brake a person pushing harder. "
            "Raise current_lim (within the motor's rating) or lower max_torque"
        )
    margin = link.read_float(prefix + "motor.config.current_lim_margin")
    return [f"current trip at {i_lim + margin:g} A (current_lim {i_lim:g} + margin {margin:g})"]


def registers(link: AsciiLink, prefix: str, fw: Firmware, beat: Callable[[], None]) -> list[str]:
    """Every non-zero error register, its bits named (``beat`` between reads: a fault's
    report takes several round trips). An unreadable one is said so."""
    out: list[str] = []
    regs = [
        ("axis", prefix + "error", fw.axis_errors),
        ("motor", prefix + "motor.error", fw.motor_errors),
        ("controller", prefix + "controller.error", CONTROLLER_ERRORS),
        ("encoder", prefix + "encoder.error", ENCODER_ERRORS),
    ]
    if fw.system_error:
        regs.append(("system", "error", SYSTEM_ERRORS))
    for name, path, table in regs:
        beat()
        try:
            code, note = link.read_flags(path)
        except MachineError as exc:
            out.append(f"{name} error unreadable ({exc})")
            continue
        if code is None:
            out.append(f"{name} error {note}")
        elif code:
            out.append(describe_bits(name, code, table) + note)
    return out


def reasons(parts: list[str]) -> str:
    """The registers' account of a fault, for a message (only the unreadable: say none set)."""
    set_ = [p for p in parts if "unreadable" not in p]
    if not set_:
        return "; ".join([*parts, "no readable error register set"])
    return "; ".join(parts)
