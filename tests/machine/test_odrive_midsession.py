"""The drive fails in the middle of a session (the emulator's fault injection), through the
whole live path: worker → ODrive backend → pty → emulated device.

Truth: the device's own registers and log, not the worker's account. The session must end
``faulted`` with the drive's reason, within the health check's period (a few ms: a deadline
of seconds here only bounds a hung test), the torque at the device zero and the axis idle
from then on, the worker latched ``faulted`` until a reset, and a reset starts nothing.
"""

from __future__ import annotations

import time

import pytest

from sessions.machine.odrive.emulator import EmulatorConfig, EmulatorProcess
from sessions.worker import Worker, WorkerOptions
from testing.live import follow, odrive, scenario, wait_for

pytestmark = pytest.mark.realtime  # a session over the emulated drive's pty: run alone

FAULTS = {  # injected → words the session's reason must hold
    "motor": "axis0",
    "overspeed": "overspeed",
    "encoder": "encoder",
}


def _driving(emu: EmulatorProcess, since: float) -> bool:
    return sum(v != 0.0 for _, v in emu.torques_since(since)) >= 50


@pytest.mark.parametrize("fault", sorted(FAULTS))
def test_a_drive_fault_mid_session_ends_it_faulted_at_zero_torque(fault: str) -> None:
    with EmulatorProcess(EmulatorConfig()) as emu:
        spec = odrive(emu.path, reply_timeout=0.2, watchdog_timeout=0.5)
        with Worker(spec, WorkerOptions()) as worker:
            worker.start()
            worker.start_session(scenario(duration=30.0), f"fault-{fault}")
            began = follow(worker, until="session_started").of("session_started")[0].t
            assert wait_for(lambda: _driving(emu, began), timeout=10.0)
            assert emu.snapshot().current_state == 8  # closed loop
            at = time.monotonic()
            emu.device_fault(fault)  # type: ignore[arg-type]
            got = follow(worker, timeout=10.0)
            end = got.end
            assert end is not None and end.status == "faulted", end
            assert FAULTS[fault] in end.reason, end.reason
            assert end.state_after == "faulted" and worker.state == "faulted"
            assert got.of("fault")
            # the session ran on for no more than a few health periods after the fault
            assert end.summary.duration < (at - began) + 1.0
            snap = emu.snapshot()
            assert snap.applied_torque == 0.0 and snap.current_state == 1
            assert all(v == 0.0 for _, v in emu.torques_since(end.t))  # none once it was seen
            worker.reset()
            follow(worker, until="reset")
            reset_at = time.monotonic()
            assert wait_for(lambda: worker.state in ("idle", "faulted"), timeout=5.0)
            assert emu.snapshot().current_state == 1  # a reset starts no motion
            assert all(v == 0.0 for _, v in emu.torques_since(reset_at))
