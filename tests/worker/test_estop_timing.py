"""E-stop and stop timed where the torque is applied, against the moment they were asked.

Independent truths: for the simulated machine, the worker's own report of when zero torque
was written (``EStopped.zero_at``, stamped right after ``machine.zero()``) and the ring's
record of every period's torque at its start time; for the ODrive, the emulated device's log
of every torque setpoint with the monotonic time it arrived at the device (host and device
share CLOCK_MONOTONIC). Bound: :data:`ZERO_WITHIN` from the moment asked, a fixed figure a
60 ms delay anywhere on the e-stop path breaks; every wait is on the condition, with a
deadline, never a fixed sleep.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from sessions.machine.odrive.emulator import EmulatorConfig, EmulatorProcess
from sessions.worker import Worker, WorkerOptions
from sessions.worker.ring import INDEX
from testing.live import follow, odrive, scenario, wait_for

pytestmark = pytest.mark.realtime  # timed where it happens: alone, after the parallel rooms

ZERO_WITHIN = 0.030  # s from the e-stop asked to zero torque at the plant / the device
PUSHING = 50  # non-zero setpoints the device must have had before (it was driving)


def test_sim_estop_zeroes_the_plant_within_the_bound() -> None:
    with Worker(options=WorkerOptions()) as worker:
        worker.start()
        reader = worker.open_reader()
        worker.start_session(scenario(duration=30.0), "estop-timed")
        follow(worker, until="timing")
        sent = worker.estop()
        got = follow(worker, reader, timeout=10)
        reader.close()
    zero_at = got.of("estop")[0].zero_at
    assert 0.0 <= zero_at - sent < ZERO_WITHIN, f"zero torque {1e3 * (zero_at - sent):.1f} ms"
    d = got.data
    mono, u = d[:, INDEX["mono"]], d[:, INDEX["u_out"]]
    assert np.count_nonzero(u[mono < sent][-200:]) > 150  # it was pushing
    late = mono[(mono >= sent) & (u != 0.0)]
    assert np.all(late < sent + ZERO_WITHIN)  # no torque applied past the bound
    assert np.all(u[mono >= zero_at] == 0.0)


def _spec(emu: EmulatorProcess):
    # I/O limits for a loaded VM (a pty's kernel worker can stall for tens of ms)
    return odrive(emu.path, reply_timeout=0.2, watchdog_timeout=0.5)


def _driving(emu: EmulatorProcess, since: float) -> bool:
    return sum(v != 0.0 for _, v in emu.torques_since(since)) >= PUSHING


def _first_zero_after(emu: EmulatorProcess, t: float) -> float | None:
    return next((at for at, v in emu.torques_since(t) if v == 0.0), None)


def test_odrive_estop_reaches_the_device_within_the_bound() -> None:
    with (
        EmulatorProcess(EmulatorConfig()) as emu,
        Worker(_spec(emu), WorkerOptions()) as worker,
    ):
        worker.start()
        cfg = scenario(duration=30.0)
        worker.start_session(cfg, "estop-device")
        start = follow(worker, until="session_started").of("session_started")[0].t
        assert wait_for(lambda: _driving(emu, start), timeout=10.0)
        sent = worker.estop()
        assert wait_for(lambda: _first_zero_after(emu, sent) is not None, timeout=5.0)
        zero = _first_zero_after(emu, sent)
        assert zero is not None and zero - sent < ZERO_WITHIN, f"{1e3 * (zero - sent):.1f} ms"
        got = follow(worker, timeout=10)
        assert got.end is not None and got.end.reason == "e-stop"
        assert all(v == 0.0 for at, v in emu.torques_since(zero))  # and nothing after it
        snap = emu.snapshot()
        assert snap.applied_torque == 0.0 and snap.current_state == 1


def test_odrive_immediate_stop_reaches_the_device_within_the_bound() -> None:
    # Stop(immediate=True): zero torque at once (no ramp), the session ends stopped, no latch
    with (
        EmulatorProcess(EmulatorConfig()) as emu,
        Worker(_spec(emu), WorkerOptions()) as worker,
    ):
        worker.start()
        worker.start_session(scenario(duration=30.0), "stop-now")
        start = follow(worker, until="session_started").of("session_started")[0].t
        assert wait_for(lambda: _driving(emu, start), timeout=10.0)
        sent = time.monotonic()
        worker.stop(immediate=True, reason="now")
        assert wait_for(lambda: _first_zero_after(emu, sent) is not None, timeout=5.0)
        zero = _first_zero_after(emu, sent)
        assert zero is not None and zero - sent < ZERO_WITHIN, f"{1e3 * (zero - sent):.1f} ms"
        got = follow(worker, timeout=10)
        assert got.end is not None and got.end.status == "stopped" and got.end.reason == "now"
        assert got.end.state_after == "idle" and worker.state == "idle"
        assert all(v == 0.0 for _, v in emu.torques_since(zero))
        # no ramp: the stop did not go through the stopping phase
        assert "stopping" not in got.kinds()
