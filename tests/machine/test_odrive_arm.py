"""The drive's own settings are checked before anything moves; a refusal says why in one line.

Each case is a drive configured wrong in the way real ones are (the emulator in its own
process, on a pty): an uncalibrated axis; the handle on the other axis; the firmware's
factory torque constant (0.04 N·m/A) or current limit (10 A); another axis' latched error
(which arming this axis must not clear where the firmware lets it be). Truth: the device's
own state (it never entered closed loop, its registers) and what the firmware does with the
settings (effective torque limit = min(torque_lim, current_lim·torque_constant)).
"""

from __future__ import annotations

import select
import time

import pytest
import serial
from pydantic import ValidationError

from sessions.config import parse_session_config
from sessions.machine import MachineError, MachineSpec, make_machine
from sessions.machine.odrive.emulator import FACTORY, EmulatorConfig, EmulatorProcess
from sessions.machine.spec import UART_BAUDRATE
from testing.live import odrive

CFG = parse_session_config({"duration": 30.0, "machine": {"max_torque": 20.0}})
# Generous link limits: these tests check what arming reads and writes, not how fast the drive
# answers, and they run in the parallel rooms, where a loaded VM stalls the emulator's pty
# past 100 ms (one did, on a clean clone's CI). A refusal still comes well before the
# closed-loop timeout (2 s), which is what "refused at once" below tells apart.
LINK = {"reply_timeout": 0.5, "watchdog_timeout": 1.0}


def _arm_refused(rig: EmulatorConfig, match: str, **spec) -> str:
    with EmulatorProcess(rig) as emu:
        m = make_machine(odrive(emu.path, **LINK, **spec))
        try:
            m.connect()
            t0 = time.monotonic()
            with pytest.raises(MachineError, match=match) as err:
                m.arm(CFG)
            assert time.monotonic() - t0 < 1.5  # refused at once, not after a timeout
        finally:
            m.close()
        snap = emu.snapshot()
        assert snap.current_state == 1 and snap.applied_torque == 0.0
        assert not snap.watchdog_enabled
        assert not [e for e in emu.events() if e[1] == "closed loop"]
    return str(err.value)


def test_an_uncalibrated_axis_is_refused_with_the_reason():
    why = _arm_refused(EmulatorConfig(calibrated=False), "axis0 cannot enter closed-loop control")
    assert "motor is not calibrated (motor.is_calibrated = 0)" in why
    assert "encoder is not ready (encoder.is_ready = 0)" in why


def test_the_wrong_axis_is_refused_with_the_reason():
    why = _arm_refused(EmulatorConfig(axis=1), "axis0 cannot enter closed-loop control")
    assert "Is the handle's motor on axis0" in why


def test_a_torque_constant_that_is_not_the_motors_is_refused():
    why = _arm_refused(EmulatorConfig(**FACTORY), "motor.config.torque_constant is 0.04 N·m/A")
    assert "this machine's motor has 0.35 N·m/A" in why and "×8.75" in why


def test_a_current_limit_below_the_sessions_torque_limit_is_refused():
    # 2 A × 0.35 N·m/A = 0.7 N·m at the motor, but the session may command 20 N·m (gear 1)
    why = _arm_refused(EmulatorConfig(current_lim=2.0), "motor.config.current_lim 2 A")
    assert "0.7 N·m at the motor" in why and "below the session's torque limit" in why


def _ask(port: serial.Serial, line: bytes) -> bytes:
    port.write(line)
    out, deadline = b"", time.monotonic() + 1.0
    while not out.endswith(b"\r\n") and time.monotonic() < deadline:
        if select.select([port.fileno()], [], [], 0.05)[0]:
            out += port.read(4096)
    return out


def test_arm_sets_the_overspeed_tolerance_and_reads_it_back():
    with EmulatorProcess(EmulatorConfig()) as emu:
        m = make_machine(odrive(emu.path, **LINK, vel_limit_tolerance=1.1))
        m.connect()
        m.arm(CFG)
        m.close()
        with serial.Serial(emu.path, timeout=0) as port:
            assert _ask(port, b"r axis0.controller.config.vel_limit_tolerance\n") == b"1.100000\r\n"
            assert _ask(port, b"r axis0.controller.config.enable_overspeed_error\n") == b"1\r\n"
    for defeats in (0.0, 0.5, float("inf"), 5.0):  # trips at any motion, or never
        with pytest.raises(ValidationError, match="vel_limit_tolerance"):
            odrive("/dev/null", vel_limit_tolerance=defeats)


@pytest.mark.parametrize(
    ("rig", "kept"),
    [
        (EmulatorConfig(firmware=(0, 5, 1)), True),  # every register writable: no sc
        (EmulatorConfig(build="source"), True),
        (EmulatorConfig(), False),  # release 0.5.6: motor.error cannot be written: sc
    ],
    ids=["0.5.1", "0.5.6-source", "0.5.6-release"],
)
def test_arming_clears_only_its_own_axis_where_the_firmware_allows(rig, kept):
    with EmulatorProcess(rig) as emu:
        with serial.Serial(emu.path, timeout=0) as port:
            port.write(b"w axis1.controller.error 1\nw axis0.encoder.error 4\n")
            assert _ask(port, b"r axis1.controller.error\n") == b"1\r\n"
        m = make_machine(odrive(emu.path, **LINK))
        m.connect()
        m.arm(CFG)  # axis0's own error is cleared either way
        notes = list(m.notes)
        m.close()
        assert emu.snapshot().encoder_error == 0
        with serial.Serial(emu.path, timeout=0) as port:
            other = _ask(port, b"r axis1.controller.error\n")
        assert other == (b"1\r\n" if kept else b"0\r\n")
        said = [n for n in notes if "sc" in n]
        assert bool(said) == (not kept)  # when sc had to be used, the machine says so
        if said:
            assert "clears axis1's errors too" in said[0]


def test_the_baud_rate_default_is_the_uarts():
    assert UART_BAUDRATE == 115_200 and odrive("/dev/x").baudrate == UART_BAUDRATE
    with pytest.raises(ValidationError, match="torque constant"):
        MachineSpec(kind="odrive", device="/dev/x")
