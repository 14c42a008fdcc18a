"""The emulated ODrive speaks the firmware's ASCII protocol, and the backend drives it right.

Independent truths: the 0.5.x firmware's documented behaviour (checksums computed by hand
here, error strings, silence on a bad checksum, 256-character lines), the emulator's own
physics observed through its snapshot (what the handle really does), and equation (1) for the
watchdog and limiter tests, which run the emulator on a synthetic clock (no timing involved).
"""

from __future__ import annotations

import math
import select
import time

import pytest
import serial

from sessions.config import parse_session_config
from sessions.machine import MachineState, make_machine
from sessions.machine.odrive.emulator import Device, EmulatorConfig, EmulatorProcess
from sessions.machine.odrive.emulator.ascii import AsciiProtocol
from sessions.machine.odrive.protocol import (
    AXIS_ERROR_CONTROLLER_FAILED,
    AXIS_ERROR_WATCHDOG_TIMER_EXPIRED,
    checksum,
    describe_axis_error,
)
from testing.live import odrive

GEAR, DIRECTION = 4.0, -1
REPLY, WATCHDOG = 0.2, 0.5  # the backend's reply timeout and the device watchdog, s


@pytest.fixture(scope="module")
def emu():
    with EmulatorProcess(EmulatorConfig(gear_ratio=GEAR, direction=DIRECTION)) as e:
        yield e


@pytest.fixture
def port(emu):
    ser = serial.Serial(emu.path, timeout=0)
    ser.reset_input_buffer()
    yield ser
    ser.write(b"c 0 0\nw axis0.requested_state 1\nw axis0.config.enable_watchdog 0\nsc\n")
    ser.close()


@pytest.fixture
def backend(emu):
    """An ODrive backend on the emulator, closed after the test even when it fails (one left
    open keeps the pty's exclusive lock: every later test of the module then cannot open it).
    Its replies may take 200 ms: on a loaded machine the emulator's process answers late, and
    these tests are about what is said, not when (test_odrive_faults.py times the faults)."""
    spec = odrive(emu.path, gear_ratio=GEAR, direction=DIRECTION, reply_timeout=REPLY,
                  watchdog_timeout=WATCHDOG)  # fmt: skip
    m = make_machine(spec)
    yield m
    m.close()


def ask(ser: serial.Serial, line: bytes, wait: float = 0.5) -> bytes:
    """Send a line, collect what comes back until ``wait`` passes without a byte."""
    ser.write(line)
    out = b""
    deadline = time.monotonic() + wait
    while time.monotonic() < deadline:
        r, _, _ = select.select([ser.fileno()], [], [], 0.05)
        if r:
            out += ser.read(4096)
            if out.endswith(b"\r\n"):
                deadline = min(deadline, time.monotonic() + 0.05)
    return out


def test_checksum_matches_hand_computation():
    # 'f' 0x66 ^ ' ' 0x20 ^ '0' 0x30 ^ ' ' 0x20 = 0x56 = 86
    assert checksum(b"f 0 ") == 86
    assert checksum(b"") == 0
    assert describe_axis_error(0x800) == "axis error 0x800 (watchdog timer expired)"


def test_raw_conversation_follows_the_firmware(port):
    assert ask(port, b"r fw_version_major\n") == b"0\r\n"
    assert ask(port, b"r fw_version_minor\n") == b"5\r\n"
    # a checksummed request gets a checksummed reply: "5" is 0x35 = 53
    assert ask(port, b"r fw_version_minor *%d\n" % checksum(b"r fw_version_minor ")) == b"5*53\r\n"
    assert ask(port, b"r fw_version_minor *1\n", wait=0.2) == b""  # bad checksum: ignored
    assert ask(port, b"x\n") == b"unknown command\r\n"
    assert ask(port, b"\n") == b"unknown command\r\n"
    assert ask(port, b"c\n") == b"invalid command format\r\n"
    assert ask(port, b"c 5 1.0\n") == b"invalid motor 5\r\n"
    assert ask(port, b"r axis0.nonsense\n") == b"invalid property\r\n"
    assert ask(port, b"w axis0.controller.config.vel_limit abc\n") == b"not implemented\r\n"
    assert ask(port, b"w axis0.current_state 8\n") == b"not implemented\r\n"  # read-only
    assert ask(port, b"u 0\n", wait=0.2) == b""  # commands that succeed say nothing
    assert ask(port, b"w axis0.controller.config.vel_limit 3.5 ; a comment\n", wait=0.2) == b""
    assert ask(port, b"r axis0.controller.config.vel_limit!") == b"3.500000\r\n"
    assert ask(port, b"x" * 300 + b"\n", wait=0.2) == b""  # over 256: dropped to its end
    assert ask(port, b"r axis0.error\n") == b"0\r\n"
    pos, vel = ask(port, b"f 0\n").split()
    assert math.isfinite(float(pos)) and math.isfinite(float(vel))
    assert len(pos.split(b".")[1]) == 6  # printf %f


def test_backend_arms_the_device_and_converts_units(emu, backend):
    cfg = parse_session_config({"machine": {"max_torque": 12.0, "max_velocity": 10.0}})
    m = backend
    m.connect()
    assert m.firmware == (0, 5, 6)
    m.arm(cfg)
    snap = emu.snapshot()
    assert snap.current_state == 8 and snap.watchdog_enabled and snap.error == 0
    m.activate()
    q_start = emu.snapshot().q
    for _ in range(200):  # a resisting torque of 0.5 N·m at the handle for ~0.2 s
        q, w, tau = m.read()
        m.write(-0.5)
        time.sleep(0.001)
    snap = emu.snapshot()
    # the device holds the motor-side setpoint: u · direction / gear
    assert snap.input_torque == pytest.approx(-0.5 * DIRECTION / GEAR, rel=1e-6)
    # what the backend reports is what the handle does (float32 feedback, a cycle apart)
    assert math.isnan(tau)
    assert q == pytest.approx(snap.q - q_start, abs=0.05)
    assert w == pytest.approx(snap.w, abs=0.1)
    assert w > 0.5  # the simulated person pushes the handle forward
    m.disarm()
    snap = emu.snapshot()
    assert snap.current_state == 1 and not snap.watchdog_enabled and snap.input_torque == 0.0
    m.close()
    assert m.state is MachineState.CLOSED


def test_backend_writes_the_device_limits(port, backend):
    cfg = parse_session_config({"machine": {"max_torque": 12.0, "max_velocity": 10.0}})
    m = backend
    m.connect()
    m.arm(cfg)
    m.close()  # close idles the axis but leaves the limits on the device
    v_motor = 10.0 * GEAR / (2 * math.pi)
    assert float(ask(port, b"r axis0.motor.config.torque_lim\n")) == pytest.approx(3.0)
    assert float(ask(port, b"r axis0.controller.config.vel_limit\n")) == pytest.approx(
        1.2 * v_motor, rel=1e-5
    )
    gain = float(ask(port, b"r axis0.controller.config.vel_gain\n"))
    assert (1.2 * v_motor - v_motor) * gain == pytest.approx(3.0, rel=1e-4)
    assert ask(port, b"r axis0.controller.config.enable_torque_mode_vel_limit\n") == b"1\r\n"
    assert float(ask(port, b"r axis0.config.watchdog_timeout\n")) == pytest.approx(WATCHDOG)
    assert ask(port, b"r axis0.controller.config.control_mode\n") == b"1\r\n"


# -- the emulated device on a synthetic clock (no I/O timing involved) ----------------------


def _device(**rig) -> tuple[Device, float]:
    emu = Device(EmulatorConfig(**rig))
    return emu, emu.t0


def _say(emu: Device, t: float, line: bytes) -> None:
    emu.catch_up(t)
    AsciiProtocol(emu).process_line(line, t)


def test_watchdog_expires_on_the_physics_clock():
    emu, t0 = _device()
    _say(emu, t0 + 0.001, b"w axis0.config.watchdog_timeout 0.05")
    _say(emu, t0 + 0.002, b"u 0")
    _say(emu, t0 + 0.002, b"w axis0.config.enable_watchdog 1")
    _say(emu, t0 + 0.003, b"w axis0.requested_state 8")
    _say(emu, t0 + 0.004, b"c 0 0.3")
    assert emu.rig_axis.state.value == 8 and emu.rig_axis.applied == 0.0
    emu.catch_up(t0 + 0.010)
    assert emu.rig_axis.applied == pytest.approx(0.3, rel=1e-6)
    last_feed = t0 + 0.040
    _say(emu, last_feed, b"c 0 0.3")
    emu.catch_up(t0 + 0.2)
    ax = emu.rig_axis
    assert ax.error.value == AXIS_ERROR_WATCHDOG_TIMER_EXPIRED
    assert ax.state.value == 1 and ax.applied == 0.0
    assert ax.tripped_at is not None
    assert 0.05 < ax.tripped_at - last_feed <= 0.05 + emu.h + 1e-9
    # the axis refuses closed loop until the error is cleared, and trips again if unfed
    _say(emu, t0 + 0.21, b"w axis0.requested_state 8")
    assert ax.state.value == 1
    _say(emu, t0 + 0.22, b"sc")
    assert ax.error.value == 0
    emu.catch_up(t0 + 0.23)
    assert ax.error.value == AXIS_ERROR_WATCHDOG_TIMER_EXPIRED


def test_torque_mode_velocity_limiter_and_overspeed():
    emu, t0 = _device()
    ax = emu.rig_axis
    _say(emu, t0 + 0.001, b"w axis0.controller.config.vel_limit 1.0")
    _say(emu, t0 + 0.001, b"w axis0.controller.config.vel_gain 2.0")
    _say(emu, t0 + 0.001, b"w axis0.motor.config.torque_lim 5.0")
    _say(emu, t0 + 0.002, b"w axis0.requested_state 8")
    emu.plant.w = 0.8 * 2 * math.pi  # 0.8 turn/s
    _say(emu, t0 + 0.002, b"c 0 4.0")
    emu.catch_up(t0 + 0.002 + 1.5 * emu.h)
    # limiter: at most (vel_limit - v)·vel_gain = (1.0 - 0.8)·2 = 0.4 N·m forward
    assert ax.applied == pytest.approx(0.4, abs=0.02)
    _say(emu, t0 + 0.01, b"c 0 -9.0")
    emu.catch_up(t0 + 0.01 + 1.5 * emu.h)
    v = emu.plant.w / (2 * math.pi)  # braking is limited too: ≥ (-vel_limit - v)·vel_gain
    assert ax.applied == pytest.approx((-1.0 - v) * 2.0, abs=0.05)
    _say(emu, t0 + 0.011, b"w axis0.controller.config.vel_gain 100")
    emu.catch_up(t0 + 0.011 + 1.5 * emu.h)
    assert ax.applied == pytest.approx(-5.0)  # now torque_lim binds
    emu.plant.w = 1.3 * 2 * math.pi  # above vel_limit_tolerance (1.2) × vel_limit
    emu.catch_up(t0 + 0.02)
    assert ax.state.value == 1 and ax.applied == 0.0
    assert ax.error.value & AXIS_ERROR_CONTROLLER_FAILED
    assert ax.ctrl_error.value == 1  # OVERSPEED


def test_the_person_pushes_only_while_the_drive_holds_the_handle():
    emu, t0 = _device()
    emu.catch_up(t0 + 0.5)
    assert emu.plant.w == 0.0 and not emu.engaged
    _say(emu, t0 + 0.5, b"w axis0.requested_state 8")
    emu.catch_up(t0 + 0.6)
    assert emu.engaged and emu.plant.w > 0.5  # τ0/J = 30 rad/s² from rest
