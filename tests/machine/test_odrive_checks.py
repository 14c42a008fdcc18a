"""The ODrive backend's pre-arm checks and its account of a fault, in-process, to the letter.

Each check runs against an emulated drive (:class:`OdriveEmulator`, served in a thread of this
process on a real pseudo-terminal) through the real :class:`AsciiLink`, as the backend calls
it. The drive is set up the way real ones go wrong: a setting written over the line as
odrivetool would (``w axis0.motor.config.torque_constant …``), a calibration flag or an error
register the firmware keeps set as the device holds it.

Independent truth: the refusals are what the operator reads, written out here in full; the
limits are the settings' own arithmetic (the drive clips at ``current_lim·torque_constant``;
Kt within 2 % of the machine's); each error bit's words are its name in the firmware's
``odrive-interface.yaml`` (0.5.1 and 0.5.6), lower-cased with ``_`` as spaces.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

from sessions.machine import MachineError
from sessions.machine.odrive.checks import (
    check_motor,
    check_ready,
    enum_write_refused,
    reasons,
    registers,
)
from sessions.machine.odrive.emulator import EmulatorConfig
from sessions.machine.odrive.emulator.pty import OdriveEmulator
from sessions.machine.odrive.link import AsciiLink
from sessions.machine.odrive.protocol import FIRMWARES

P = "axis0."
KT = 0.35  # N·m/A: the rig's motor (EmulatorConfig's default), and the machine's setting
READY = "calibrate it (odrivetool: requested_state = AXIS_STATE_FULL_CALIBRATION_SEQUENCE) and save"


@contextmanager
def drive(rig: EmulatorConfig | None = None) -> Iterator[tuple[OdriveEmulator, AsciiLink]]:
    """An emulated drive in a thread and the backend's own link to it (generous timeout: the
    emulator shares this process' GIL on a loaded machine)."""
    with OdriveEmulator(rig or EmulatorConfig()) as emu:
        link = AsciiLink(emu.path, 115_200, 1.0, use_checksum=True)
        link.open()
        link.uint_suffix = emu.device.fw.uint_suffix
        try:
            yield emu, link
        finally:
            link.close()


def _set(emu: OdriveEmulator, axis: int, name: str, value: float | int | bool) -> None:
    """A property as the device holds it (also those the line cannot write)."""
    with emu.lock:
        emu.device.axes[axis].set(name, value)


def _write(link: AsciiLink, path: str, value: float) -> float:
    """Write a setting over the line as odrivetool would; the value the drive holds."""
    refused, back = link.write(path, value, then=path)
    assert refused is None
    return float(back)


# -- check_ready: motor calibrated, encoder ready --------------------------------------------------


def _refusal(axis: int, *missing: str) -> str:
    return (
        f"axis{axis} cannot enter closed-loop control: {'; '.join(missing)}. Is the handle's "
        f"motor on axis{axis} (setting axis)? If so, {READY}"
    )


MOTOR = "the motor is not calibrated (motor.is_calibrated = 0)"
ENCODER = "the encoder is not ready (encoder.is_ready = 0)"


@pytest.mark.parametrize(
    ("calibrated", "ready", "missing"),
    [
        (False, True, [MOTOR]),
        (True, False, [ENCODER]),
        (False, False, [MOTOR, ENCODER]),
    ],
    ids=["motor", "encoder", "both"],
)
def test_an_axis_that_cannot_enter_closed_loop_is_refused_naming_each_reason(
    calibrated, ready, missing
):
    with drive() as (emu, link):
        _set(emu, 0, "motor.is_calibrated", calibrated)
        _set(emu, 0, "encoder.is_ready", ready)
        with pytest.raises(MachineError) as got:
            check_ready(link, P, 0)
        assert str(got.value) == _refusal(0, *missing)


def test_a_ready_axis_passes_and_the_refusal_names_the_axis_checked():
    with drive(EmulatorConfig(axis=1)) as (_, link):  # the motor on axis1: axis0 has none
        assert check_ready(link, "axis1.", 1) is None
        with pytest.raises(MachineError) as got:
            check_ready(link, P, 0)
        assert str(got.value) == _refusal(0, MOTOR, ENCODER)


# -- check_motor: the torque constant and the current limit ---------------------------------------


def _kt_refusal(kt: str, expected: str, factor: str) -> str:
    return (
        f"motor.config.torque_constant is {kt} N·m/A but this machine's motor has "
        f"{expected} N·m/A (setting torque_constant): every torque, and the drive's torque "
        f"limit, would be off by ×{factor}. Set the drive's to the motor's (8.27/Kv), or "
        "correct the setting"
    )


def test_a_drive_that_holds_the_motors_settings_passes_and_says_where_the_current_trips():
    with drive() as (_, link):
        _write(link, P + "motor.config.current_lim_margin", 5.5)
        # 60 A × 0.35 N·m/A = 21 N·m: the session's 20 N·m at the motor are within it
        notes = check_motor(link, P, KT, 20.0, 1.0)
        assert notes == ["current trip at 65.5 A (current_lim 60 + margin 5.5)"]


@pytest.mark.parametrize(
    ("kt", "shown"),
    [(0.0, "0.0"), (-0.35, "-0.35"), (math.inf, "inf"), (math.nan, "nan")],
)
def test_a_torque_constant_that_is_no_torque_constant_is_refused(kt, shown):
    with drive() as (emu, link):
        _set(emu, 0, "motor.config.torque_constant", kt)
        with pytest.raises(MachineError) as got:
            check_motor(link, P, KT, 1.0, 1.0)
        assert str(got.value) == f"motor.config.torque_constant is {shown}: not a torque constant"


@pytest.mark.parametrize(
    ("held", "expected", "factor"),
    [(0.04, "0.35", "8.75"), (0.4, "0.35", "0.875"), (0.35, "0.3", "0.857")],
    ids=["factory", "high", "setting-low"],
)
def test_a_torque_constant_that_is_not_the_motors_is_refused_by_how_far_it_is_off(
    held, expected, factor
):
    with drive() as (_, link):
        kt = _write(link, P + "motor.config.torque_constant", held)
        with pytest.raises(MachineError) as got:
            check_motor(link, P, float(expected), 1.0, 1.0)
        assert str(got.value) == _kt_refusal(f"{kt:g}", expected, factor)


def test_the_torque_constant_may_be_off_by_2_percent_either_way_and_no_more():
    # the drive holds 0.35 N·m/A (a float32 printed %f: 0.350000); the setting moves around it
    with drive() as (_, link):
        for setting in (0.35 / 1.0199, 0.35 / 0.9801, 0.35):  # Kt 1.99 % above, below, equal
            assert check_motor(link, P, setting, 1.0, 1.0)
        for setting in (0.35 / 1.0201, 0.35 / 0.9799):  # 2.01 % off
            with pytest.raises(MachineError, match="but this machine's motor has"):
                check_motor(link, P, setting, 1.0, 1.0)
        # exactly 2 % either way, to the last bit: 51/64 and 49/64 against 25/32 N·m/A
        for held in (0.796875, 0.765625):
            assert _write(link, P + "motor.config.torque_constant", held) == held
            assert abs(held - 0.78125) == 0.02 * 0.78125
            assert check_motor(link, P, 0.78125, 1.0, 1.0)


@pytest.mark.parametrize(("lim", "shown"), [(0.0, "0.0"), (-5.0, "-5.0"), (math.inf, "inf")])
def test_no_current_limit_is_refused(lim, shown):
    with drive() as (emu, link):
        _set(emu, 0, "motor.config.current_lim", lim)
        with pytest.raises(MachineError) as got:
            check_motor(link, P, KT, 1.0, 1.0)
        assert str(got.value) == f"motor.config.current_lim is {shown} A: no current limit"


def test_a_current_limit_below_the_sessions_torque_limit_is_refused_with_the_arithmetic():
    with drive() as (_, link):
        _write(link, P + "motor.config.current_lim", 2.0)
        # 2 A × 0.35 N·m/A = 0.7 N·m at the motor, × gear 3 = 2.1 N·m at the handle
        with pytest.raises(MachineError) as got:
            check_motor(link, P, KT, 4.0, 3.0)
        assert str(got.value) == (
            "motor.config.current_lim 2 A × torque_constant 0.35 N·m/A = 0.7 N·m at the motor "
            "(2.1 N·m at the handle) is below the session's torque limit (4 N·m at the "
            "motor): the drive would cut larger commands without a word, and could not brake "
            "a person pushing harder. Raise current_lim (within the motor's rating) or lower "
            "max_torque"
        )


def test_the_current_limit_must_reach_the_torque_limit_to_a_millionth():
    with drive() as (_, link):
        _write(link, P + "motor.config.current_lim", 2.0)
        most = 2.0 * KT  # what the drive can give, N·m at the motor
        assert check_motor(link, P, KT, most, 1.0)  # exactly the limit
        assert check_motor(link, P, KT, most * (1.0 + 0.5e-6), 1.0)  # float32 settings' slack
        with pytest.raises(MachineError, match="is below the session's torque limit"):
            check_motor(link, P, KT, most * (1.0 + 2e-6), 1.0)
        # the slack's own edge: 0.7000007000007 × (1 - 1e-6) is 0.7 N·m to the last bit
        assert most == 0.7000007000007 * (1.0 - 1e-6)
        assert check_motor(link, P, KT, 0.7000007000007, 1.0)


def test_a_current_limit_below_one_ampere_is_a_current_limit():
    with drive() as (_, link):
        _write(link, P + "motor.config.current_lim", 0.5)  # a small motor: 0.175 N·m
        assert check_motor(link, P, KT, 0.175, 1.0) == [
            "current trip at 8.5 A (current_lim 0.5 + margin 8)"
        ]


def test_a_build_that_refuses_enum_writes_is_told_to_update():
    assert str(enum_write_refused(FIRMWARES[(0, 5, 3)])) == (
        "ODrive firmware 0.5.3: this build answers 'not implemented' to enum writes (the bug "
        "of the released 0.5.3 binaries, fixed in 0.5.4); update the firmware"
    )


# -- registers and reasons: a fault's account --------------------------------------------------


def _name(enum: str) -> str:
    return enum.lower().replace("_", " ")


# register path: (the word for it, a bit, the bit's name in the firmware's odrive-interface.yaml)
FIRMWARE_BITS = {
    "error": ("axis", 0x4000, "ESTOP_REQUESTED"),  # ODrive.Axis.Error
    "motor.error": ("motor", 0x1000, "CURRENT_LIMIT_VIOLATION"),  # ODrive.Motor.Error
    "controller.error": ("controller", 0x1, "OVERSPEED"),  # ODrive.Controller.Error
    "encoder.error": ("encoder", 0x4, "NO_RESPONSE"),  # ODrive.Encoder.Error
}


def _beats() -> tuple[list[int], object]:
    count = [0]

    def beat() -> None:
        count[0] += 1

    return count, beat


@pytest.mark.parametrize("fw", [(0, 5, 1), (0, 5, 6)], ids=["0.5.1", "0.5.6"])
def test_every_register_set_is_named_with_its_bits_and_a_beat_between_reads(fw):
    with drive(EmulatorConfig(firmware=fw, build="source")) as (emu, link):
        count, beat = _beats()
        assert registers(link, P, FIRMWARES[fw], beat) == []
        assert count[0] == (4 if fw == (0, 5, 1) else 5)  # 0.5.2+: the system error too
        for path, (_, bit, _) in FIRMWARE_BITS.items():
            _set(emu, 0, path, bit)
        _set(emu, 1, "error", 0x800)  # the other axis is not this axis' account
        got = registers(link, P, FIRMWARES[fw], beat)
        want = [
            f"{word} error 0x{bit:x} ({_name(enum)})" for word, bit, enum in FIRMWARE_BITS.values()
        ]
        assert got == want
        with emu.lock:
            emu.device.system_error = 0x2  # ODrive.Error.DC_BUS_UNDER_VOLTAGE (0.5.2+)
        got = registers(link, P, FIRMWARES[fw], beat)
        system = "system error 0x2 (DC bus under voltage)"
        assert got == (want if fw == (0, 5, 1) else [*want, system])


def test_a_register_that_cannot_be_read_is_said_so_and_the_others_still_read():
    with drive() as (emu, link):  # release 0.5.6: motor.error prints "lu"
        _set(emu, 0, "encoder.error", 0x4)
        emu.inject("garbage", count=1)  # the axis error's reply
        got = registers(link, P, FIRMWARES[(0, 5, 6)], lambda: None)
        assert len(got) == 3
        assert re.fullmatch(
            r"axis error unreadable \(garbled reply .*to b'r axis0\.error \*\d+\\n': .+\)", got[0]
        )
        assert got[1:] == [
            "motor error unreadable: this firmware build prints 64-bit integers as 'lu'",
            "encoder error 0x4 (no response)",
        ]


def test_a_register_cut_at_9_digits_says_so():
    with drive(EmulatorConfig(build="source")) as (emu, link):
        _set(emu, 0, "encoder.error", 0x4000_0000)  # 1073741824: printed 107374182
        (got,) = registers(link, P, FIRMWARES[(0, 5, 6)], lambda: None)
        assert got.startswith("encoder error 0x6666666 (")
        assert got.endswith(
            "unknown bits 0x6666400) (as printed: the firmware cuts replies at 9 digits)"
        )


def test_reasons_say_when_no_readable_register_is_set():
    assert reasons([]) == "no readable error register set"
    unread = ["motor error unreadable: this firmware build prints 64-bit integers as 'lu'"]
    assert reasons(unread) == f"{unread[0]}; no readable error register set"
    both = [unread[0], "axis error unreadable (timeout)", "encoder error 0x4 (no response)"]
    assert reasons(both) == "; ".join(both)
    assert reasons(["axis error 0x4000 (estop requested)"]) == "axis error 0x4000 (estop requested)"
