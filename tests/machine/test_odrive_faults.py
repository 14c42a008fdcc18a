"""A misbehaving serial line is a fault with zero torque, never a hang.

The emulator (its own process) is made to misbehave the way real lines do: garbage bytes, a
short reply, a reply without its line end, silence, an unsolicited line, a wrong checksum; or
it dies. The backend must raise a MachineError within its reply timeout (asserted with a wide
margin: this is about not hanging, not about speed), latch FAULT, and the device must end up
with zero torque: commanded by the backend when the line still works, by the device's own
watchdog when it does not.
"""

from __future__ import annotations

import time

import pytest

from sessions.config import parse_session_config
from sessions.machine import MachineError, MachineState, make_machine
from sessions.machine.odrive.emulator import AXIS_COUNT, EmulatorConfig, EmulatorProcess
from sessions.machine.odrive.protocol import AXIS_ERROR_WATCHDOG_TIMER_EXPIRED
from sessions.worker import Worker, WorkerError, WorkerOptions
from testing.live import follow, odrive, scenario, wait_for

CFG = parse_session_config({"duration": 30.0})
pytestmark = pytest.mark.realtime  # a 20 ms reply timeout: alone, after the parallel rooms

TIMEOUT = 0.02


def armed(emu, **spec):
    m = make_machine(odrive(emu.path, reply_timeout=TIMEOUT, **spec))
    m.connect()
    m.arm(CFG)
    m.activate()
    for _ in range(20):
        m.read()
        m.write(-0.2)
    return m


@pytest.mark.parametrize(
    ("injection", "message"),
    [
        ("garbage", "garbled"),
        ("short", "short or garbled feedback"),
        ("partial", "timeout: partial line"),
        ("silence", "timeout: no reply"),
        ("extra", "unexpected data"),
        ("bad-checksum", "bad checksum"),
    ],
)
def test_line_faults_become_latched_faults_with_zero_torque(emu, injection, message):
    m = armed(emu)
    try:
        emu.inject(injection, count=1)
        t0 = time.monotonic()
        with pytest.raises(MachineError, match=message):
            for _ in range(3):  # the fault shows on this cycle's reply, or the next one's
                m.read()
                m.write(-0.2)
        assert time.monotonic() - t0 < 1.0  # bounded by the reply timeout: no hang
        assert m.state is MachineState.FAULT
        assert m.fault_reason and m.last_command == 0.0
        with pytest.raises(MachineError, match="latched"):
            m.arm(CFG)
        emu.inject(None)
        # zero torque reaches the device: sent by the backend, or (if the line is silent)
        # the watchdog's doing within its 50 ms timeout
        assert wait_for(lambda: emu.snapshot().applied_torque == 0.0, timeout=1.0)
        snap = emu.snapshot()
        assert snap.input_torque == 0.0 or snap.error & AXIS_ERROR_WATCHDOG_TIMER_EXPIRED
        assert snap.current_state == 1
        m.reset()  # a reset reconnects and clears the device's errors; it arms nothing
        assert m.state is MachineState.CONNECTED
        assert emu.snapshot().error == 0 and emu.snapshot().current_state == 1
    finally:
        emu.inject(None)
        m.close()


def test_a_checksum_free_link_still_catches_garbage(emu):
    m = armed(emu, checksum=False)
    try:
        emu.inject("garbage", count=1)
        with pytest.raises(MachineError, match="garbled"):
            for _ in range(3):
                m.read()
                m.write(0.0)
    finally:
        emu.inject(None)
        m.close()


def test_a_vanished_device_is_a_fault_not_a_hang():
    emu = EmulatorProcess(EmulatorConfig())
    m = armed(emu)
    try:
        emu._proc.kill()  # the device is unplugged: the pty goes away
        emu._proc.join(5)
        t0 = time.monotonic()
        with pytest.raises(MachineError):
            for _ in range(5):
                m.read()
                m.write(0.0)
        assert time.monotonic() - t0 < 1.0
        assert m.state is MachineState.FAULT
    finally:
        m.close()
        emu.close()


def test_connect_refuses_a_wrong_device(tmp_path):
    m = make_machine(odrive(str(tmp_path / "nothing")))
    with pytest.raises(MachineError, match="cannot open"):
        m.connect()
    assert m.state is MachineState.FAULT


def test_worker_session_faults_on_garbage_and_stays_latched(emu):
    spec = odrive(emu.path, reply_timeout=0.2, watchdog_timeout=0.5)
    with Worker(spec, WorkerOptions()) as worker:
        worker.start()
        worker.start_session(scenario(duration=20.0), "garbled")
        follow(worker, until="session_started", timeout=30)
        time.sleep(0.3)
        emu.inject("garbage", count=1)
        got = follow(worker, timeout=10)
        assert got.end is not None and got.end.status == "faulted"
        assert "garbled" in got.end.reason
        assert got.end.state_after == "faulted"
        assert got.of("fault")
        assert worker.status().state == "faulted"
        assert wait_for(lambda: emu.snapshot().applied_torque == 0.0, timeout=1.0)
        with pytest.raises(WorkerError, match="faulted"):
            worker.start_session(scenario(), "refused")
        worker.reset()
        follow(worker, until="reset", timeout=10)
        assert worker.status().state == "idle"
        snap = emu.snapshot()
        assert snap.current_state == 1 and snap.error == 0  # reset moved nothing
        assert AXIS_COUNT == 2
