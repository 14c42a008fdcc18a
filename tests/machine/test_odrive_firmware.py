"""Each ODrive firmware, 0.5.1 … 0.5.6, as the emulator mimics it; the backend against each.

Independent truth: what the firmware sources and release notes say each version does (the
expectations below are written from them, not from the emulator): ``sc`` first appears in
0.5.2 ("`sc` command to ascii protocol", 0.5.2 changelog); 0.5.1's ``ASCII_protocol_process_line``
ends ``else if (cmd[0] != 0) respond("unknown command")`` (an empty line: no reply); the
limiter is ``enable_current_mode_vel_limit`` in 0.5.1's interface YAML; fibre-cpp's
``format_traits_t<unsigned int>`` prints ``"%ud"`` until 0.5.4 ("r axis0.error returned 0d
instead of 0", fixed in 0.5.4); 64-bit integers print ``lu`` on the newlib-nano release builds
(ODrive issue #571); 0.5.2-0.5.3 release binaries answer enum writes ``not implemented``
(0.5.4 changelog); the axis MOTOR_FAILED/ENCODER_FAILED/CONTROLLER_FAILED bits exist in 0.5.1
and again from 0.5.5, not in 0.5.2-0.5.4; 0.5.2 moved the DC-bus faults to the system error.
"""

from __future__ import annotations

import time

import pytest

from sessions.config import parse_session_config
from sessions.machine import MachineError, MachineState, make_machine
from sessions.machine.odrive.checks import accept_firmware
from sessions.machine.odrive.emulator import Device, EmulatorConfig, EmulatorProcess
from sessions.machine.odrive.emulator.ascii import AsciiProtocol
from sessions.machine.odrive.protocol import (
    AXIS_ERROR_WATCHDOG_TIMER_EXPIRED,
    SUPPORTED,
)
from testing.live import odrive, wait_for

ALL = [(0, 5, r) for r in range(1, 7)]
CFG = parse_session_config({"duration": 30.0})


def _talk(fw: tuple[int, int, int], build: str = "release"):
    dev = Device(EmulatorConfig(firmware=fw, build=build))
    proto = AsciiProtocol(dev)

    def say(line: bytes) -> list[bytes]:
        dev.catch_up(dev.t_phys)
        return proto.process_line(line, dev.t_phys)

    return dev, say


@pytest.mark.parametrize("fw", ALL, ids=lambda v: ".".join(map(str, v)))
def test_the_emulator_speaks_each_firmware(fw):
    rev = fw[2]
    _, say = _talk(fw)
    assert say(b"r fw_version_revision") == [b"%d" % rev]
    assert say(b"") == ([] if rev == 1 else [b"unknown command"])
    # unsigned error registers: "%ud" in 0.5.2-0.5.3
    assert say(b"r axis0.error") == ([b"0d"] if rev in (2, 3) else [b"0"])
    # the 64-bit motor.error of 0.5.2+: "lu" on the release builds, and not writable there
    assert say(b"r axis0.motor.error") == ([b"0"] if rev == 1 else [b"lu"])
    assert say(b"w axis0.motor.error 0") == ([] if rev == 1 else [b"not implemented"])
    # the limiter's name
    old, new = (
        b"r axis0.controller.config.enable_%s_mode_vel_limit" % m for m in (b"current", b"torque")
    )
    assert say(old) == ([b"1"] if rev <= 2 else [b"invalid property"])
    assert say(new) == ([b"invalid property"] if rev <= 2 else [b"1"])
    # the system error exists from 0.5.2
    assert say(b"r error") == ([b"invalid property"] if rev == 1 else [b"0d" if rev < 4 else b"0"])
    # enum writes: refused by the 0.5.2-0.5.3 release binaries
    refused = [b"not implemented"] if rev in (2, 3) else []
    assert say(b"w axis0.requested_state 1") == refused
    assert say(b"w axis0.controller.config.control_mode 1") == refused
    # sc: ignored by 0.5.1; from 0.5.2 it clears both axes
    if rev not in (2, 3):
        assert say(b"w axis1.controller.error 1") == []
        say(b"sc")
        assert say(b"r axis1.controller.error") == ([b"1"] if rev == 1 else [b"0"])
    # every r reply fits the firmware's 10-byte buffer: a 10-digit value is cut to 9
    if rev not in (2, 3):
        say(b"w axis0.encoder.error 1073741824")
        assert say(b"r axis0.encoder.error") == [b"107374182"]


@pytest.mark.parametrize("fw", ALL, ids=lambda v: ".".join(map(str, v)))
def test_a_source_build_prints_and_parses_every_integer(fw):
    _, say = _talk(fw, build="source")
    assert say(b"w axis0.motor.error 4096") == []
    assert say(b"r axis0.motor.error") == [b"4096"]  # %llu (64-bit) or %d (0.5.1's 32-bit)
    assert say(b"w axis0.requested_state 1") == []


AXIS_BITS = {  # the axis bit a fault of the part sets, per firmware (0: none)
    "motor": {1: 0x40, 2: 0, 3: 0, 4: 0, 5: 0x40, 6: 0x40},
    "encoder": {1: 0x100, 2: 0, 3: 0, 4: 0, 5: 0x100, 6: 0x100},
    "overspeed": {1: 0x200, 2: 0, 3: 0, 4: 0, 5: 0x200, 6: 0x200},
    "estop": dict.fromkeys(range(1, 7), 0x4000),
    "undervoltage": {1: 0x2, 2: 0, 3: 0, 4: 0, 5: 0x40, 6: 0x40},
}


@pytest.mark.parametrize("fw", ALL, ids=lambda v: ".".join(map(str, v)))
@pytest.mark.parametrize("fault", sorted(AXIS_BITS))
def test_faults_land_in_each_firmwares_registers(fw, fault):
    dev, say = _talk(fw, build="source")
    say(b"w axis0.requested_state 8")
    assert dev.rig_axis.state.value == 8
    dev.fault(fault, dev.t_phys)  # type: ignore[arg-type]
    snap = dev.snapshot(dev.t_phys)
    rev = fw[2]
    assert snap.current_state == 1 and snap.applied_torque == 0.0
    assert snap.error == AXIS_BITS[fault][rev]
    if fault == "motor":
        assert snap.motor_error == 0x1000  # CURRENT_LIMIT_VIOLATION, the same bit in all
    if fault == "overspeed":
        assert snap.controller_error == 0x1
    if fault == "encoder":
        assert snap.encoder_error == 0x4
        # from 0.5.2, 'f' without a valid estimate answers zeros (0.5.1: the stale estimate)
        dev.plant.q = 1.0
        zero = say(b"f 0") == [b"0.000000 0.000000"]
        assert zero == (rev >= 2)
    if fault == "undervoltage":
        assert snap.system_error == (0 if rev == 1 else 0x2)


def test_the_firmware_policy():
    for version in SUPPORTED:
        assert accept_firmware(version, "supported").version == version
    with pytest.raises(MachineError) as got:
        accept_firmware((0, 6, 1), "supported")
    assert str(got.value) == (
        "unsupported ODrive firmware 0.6.1: supported are 0.5.1, 0.5.4, 0.5.5, 0.5.6 "
        "(ODrive v3.x, ASCII protocol)"
    )
    for rev in (2, 3):
        with pytest.raises(MachineError) as got:
            accept_firmware((0, 5, rev), "supported")
        why = str(got.value)
        assert why.startswith(f"ODrive firmware 0.5.{rev} is refused: ")
        assert why.endswith(
            "; update to 0.5.4 or later (firmware_policy = 'probe' accepts a build of your "
            "own that has not the bug)"
        )
        assert accept_firmware((0, 5, rev), "probe").enum_write_bug


def _spec(emu, **kw):
    # generous I/O limits (a loaded VM's pty stalls for tens of ms); the watchdog still trips
    return odrive(emu.path, reply_timeout=0.2, watchdog_timeout=0.3, **kw)


def _cycles(m, n: int = 50) -> None:
    for _ in range(n):
        m.read()
        m.write(-0.2)
        time.sleep(0.0005)


BUILDS = [(v, "release") for v in SUPPORTED] + [((0, 5, 6), "source"), ((0, 5, 3), "source")]


@pytest.mark.parametrize(
    ("fw", "build"), BUILDS, ids=[f"{'.'.join(map(str, v))}-{b}" for v, b in BUILDS]
)
def test_the_backend_drives_each_firmware_and_disarms_the_watchdog_after_a_fault(fw, build):
    policy = "probe" if fw in ((0, 5, 2), (0, 5, 3)) else "supported"
    with EmulatorProcess(EmulatorConfig(firmware=fw, build=build)) as emu:
        m = make_machine(_spec(emu, firmware_policy=policy))
        try:
            m.connect()
            assert m.firmware == fw
            m.arm(CFG)
            m.activate()
            _cycles(m)
            snap = emu.snapshot()
            assert snap.current_state == 8 and snap.watchdog_enabled and snap.error == 0
            emu.device_fault("estop")
            with pytest.raises(MachineError, match=r"axis error 0x4000 \(estop requested\)"):
                _cycles(m, 200)
            assert m.state is MachineState.FAULT
            # after the fault the watchdog is off: the idle axis latches nothing on top
            time.sleep(0.9)  # well past the 0.3 s watchdog timeout
            snap = emu.snapshot()
            assert snap.current_state == 1 and not snap.watchdog_enabled
            assert snap.error == 0x4000 and not snap.error & AXIS_ERROR_WATCHDOG_TIMER_EXPIRED
            m.reset()
            assert emu.snapshot().error == 0
            m.arm(CFG)  # and it runs again
            m.activate()
            _cycles(m)
            m.disarm()
            snap = emu.snapshot()
            assert snap.current_state == 1 and not snap.watchdog_enabled and snap.error == 0
        finally:
            m.close()


@pytest.mark.parametrize("fw", [(0, 5, 2), (0, 5, 3)], ids=["0.5.2", "0.5.3"])
def test_the_released_0_5_2_and_0_5_3_are_refused_at_connect(fw):
    with EmulatorProcess(EmulatorConfig(firmware=fw)) as emu:
        m = make_machine(_spec(emu))
        with pytest.raises(MachineError, match=r"refused: .*update to 0\.5\.4 or later"):
            m.connect()
        m.close()
        m = make_machine(_spec(emu, firmware_policy="probe"))  # the operator vouches: proven
        with pytest.raises(MachineError, match=r"this build answers 'not implemented'"):
            m.connect()
        m.close()
        assert not [e for e in emu.events() if e[1] == "closed loop"]


EXPECTED = {  # what the fault's reason must name, per firmware (source builds: all readable)
    (0, 5, 1): {
        "motor": ["axis error 0x40 (motor failed)", "motor error 0x1000 (current limit violation)"],
        "encoder": ["axis error 0x100 (encoder failed)", "encoder error 0x4 (no response)"],
        "overspeed": ["axis error 0x200 (controller failed)", "controller error 0x1 (overspeed)"],
        "undervoltage": ["axis error 0x2 (DC bus under voltage)"],
    },
    (0, 5, 4): {
        "motor": ["left closed-loop control", "motor error 0x1000 (current limit violation)"],
        "encoder": ["left closed-loop control", "encoder error 0x4 (no response)"],
        "overspeed": [
            "controller error 0x1 (overspeed)",
            "motor error 0x10000000 (unknown torque)",
        ],
        "undervoltage": ["system error 0x2 (DC bus under voltage)", "system level"],
    },
    (0, 5, 6): {
        "motor": ["axis error 0x40 (motor failed)", "motor error 0x1000 (current limit violation)"],
        "encoder": ["axis error 0x100 (encoder failed)", "encoder error 0x4 (no response)"],
        "overspeed": ["axis error 0x200 (controller failed)", "controller error 0x1 (overspeed)"],
        "undervoltage": ["axis error 0x40 (motor failed)", "system error 0x2 (DC bus under"],
    },
}


@pytest.mark.parametrize("fw", sorted(EXPECTED), ids=lambda v: ".".join(map(str, v)))
def test_fault_reasons_read_every_register_and_name_the_bits(fw):
    with EmulatorProcess(EmulatorConfig(firmware=fw, build="source")) as emu:
        m = make_machine(_spec(emu))
        try:
            m.connect()
            for fault, words in EXPECTED[fw].items():
                m.arm(CFG)
                m.activate()
                _cycles(m, 20)
                emu.device_fault(fault)  # type: ignore[arg-type]
                with pytest.raises(MachineError) as err:
                    _cycles(m, 200)
                for w in words:
                    assert w in str(err.value), (fault, str(err.value))
                m.reset()
        finally:
            m.close()


def test_a_release_build_says_the_motor_error_is_unreadable():
    with EmulatorProcess(EmulatorConfig(firmware=(0, 5, 4))) as emu:
        m = make_machine(_spec(emu))
        try:
            m.connect()
            m.arm(CFG)
            m.activate()
            _cycles(m, 20)
            emu.device_fault("motor")
            with pytest.raises(MachineError, match="left closed-loop control") as err:
                _cycles(m, 200)
            assert "motor error unreadable: this firmware build prints 64-bit integers as 'lu'" in (
                str(err.value)
            )
        finally:
            m.close()


@pytest.mark.parametrize("partial", ["c 0 0.3", "w axis0.requested_state 8", "r axis0.err"])
def test_a_partial_line_in_the_device_is_dropped_never_executed(partial):
    with EmulatorProcess(EmulatorConfig(partial_line=partial)) as emu:
        t0 = time.monotonic() - 60.0
        m = make_machine(_spec(emu))
        try:
            m.connect()  # a bare newline would have run the partial command
            assert m.firmware == (0, 5, 6)
            snap = emu.snapshot()
            assert snap.input_torque == 0.0 and snap.current_state == 1
            assert emu.torques_since(t0) == []
            assert not [e for e in emu.events() if e[1] == "closed loop"]
            assert snap.ignored_checksum == 1  # the merged line: dropped for its checksum
            m.arm(CFG)  # and the line is in step
            assert wait_for(lambda: emu.snapshot().current_state == 8, 1.0)
        finally:
            m.close()
