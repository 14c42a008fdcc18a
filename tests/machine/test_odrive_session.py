"""Whole sessions through the ODrive backend, the emulated device on a pty in its own process.

1. A seeking session (at 500 Hz) reaches the optimum the pure simulation reaches. The live
   run cannot be step-for-step identical (the device's physics runs on its own clock, feedback
   is float32 text a fraction of a period old, a loaded machine skips periods), so the
   comparison is on what the seeker is for: its final answer. Tolerance: the seeker stops when
   its bracket
   is narrower than ``threshold`` (0.1 rad/s) and both brackets hold the maximiser of the same
   noise-free user, so the two answers differ by less than ``threshold``; and both must reach
   p(wd)/p* ≥ 0.99 of the user's true maximum (the SPEC's criterion: near the optimum p is
   flat, ±10 % in w costs ~1 % in p).
2. SIGKILL of the worker: the device's watchdog brings the torque to zero by itself, within its
   timeout of the last command the worker sent (checked on the device's physics clock).
3. E-stop: the device receives at most two non-zero torque setpoints after the e-stop was sent,
   then zero; the axis is idle and stays so after a reset.
"""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest

from sessions.machine.odrive.emulator import EmulatorConfig, EmulatorProcess
from sessions.machine.odrive.protocol import AXIS_ERROR_WATCHDOG_TIMER_EXPIRED
from sessions.people import SimulatedUser
from sessions.simulation import run_simulation
from sessions.worker import Worker, WorkerOptions
from testing.live import follow, odrive, scenario, wait_for

pytestmark = pytest.mark.realtime  # a session over the emulated drive's pty: run alone

GEAR, DIRECTION = 4.0, -1


@pytest.fixture
def rig():
    cfg = scenario(duration=9.0)
    with EmulatorProcess(
        EmulatorConfig.from_session(cfg, gear_ratio=GEAR, direction=DIRECTION)
    ) as emu:
        yield cfg, emu


def _commanded(emu, since: float) -> int:
    """Non-zero torque setpoints the device received since ``since``."""
    return sum(v != 0.0 for _, v in emu.torques_since(since))


def spec(emu, **kw):
    # generous I/O limits: host and device share a loaded VM, where a pty's kernel worker can
    # stall for tens of ms; the defaults (20 ms reply, 50 ms watchdog) are for hardware
    base = {"reply_timeout": 0.2, "watchdog_timeout": 0.5}
    return odrive(emu.path, gear_ratio=GEAR, direction=DIRECTION, **{**base, **kw})


def test_seeking_through_the_odrive_reaches_the_simulated_optimum(rig):
    _, emu = rig
    # 500 Hz, the rate the ODrive link must sustain: on a loaded 2-core VM the pty's wake-up
    # latency makes a 1 kHz loop skip 1-20 % of its periods, which blurs the comparison (the
    # 1 kHz link is exercised by the other tests here and measured by benchmarks/odrive_pty.py)
    cfg = scenario(duration=9.0, rate=500.0)  # the person the emulator was given
    ref = run_simulation(cfg)
    assert ref.progress.done
    with Worker(spec(emu), WorkerOptions()) as worker:
        worker.start()
        worker.start_session(cfg, "odrive-seek")
        got = follow(worker, timeout=60)
    end = got.end
    assert end is not None and end.status == "completed", end
    assert end.summary.converged
    live, offline = end.summary.optimum_w, ref.progress.target
    assert live is not None
    evs = [(round(e.candidate, 3), round(e.power, 4)) for e in got.of("evaluation")]
    why = f"live {live:.4f}, offline {offline:.4f}, live evaluations {evs}, {end.timing}"
    # The same optimum to within what the search can tell apart: both inside the band where
    # the user's true power is ≥ 99 % of p*, and no further apart than half its width. (Closer
    # than that is chance: on a loaded VM the link skips periods, which adds measurement noise.)
    user = SimulatedUser(cfg.user, cfg.dt, cfg.seed)
    _, p_star = user.optimum()
    grid = np.linspace(0.5, 9.5, 9001)
    band = grid[[user.true_power(w) / p_star >= 0.99 for w in grid]]
    assert user.true_power(live) / p_star >= 0.99, why
    assert user.true_power(offline) / p_star >= 0.99
    assert abs(live - offline) <= 0.5 * (band[-1] - band[0]), why
    snap = emu.snapshot()
    assert snap.current_state == 1 and snap.applied_torque == 0.0 and snap.error == 0
    assert not snap.watchdog_enabled


def test_sigkill_of_the_worker_trips_the_device_watchdog(rig):
    cfg, emu = rig
    timeout = 0.1  # the 50 ms default is checked on the device's own clock in
    # test_odrive_protocol; here the link must not fault on a loaded VM before the kill
    with Worker(spec(emu, watchdog_timeout=timeout, reply_timeout=0.08), WorkerOptions()) as worker:
        worker.start()
        worker.start_session(cfg, "killed")
        began = follow(worker, until="session_started").of("session_started")[0].t
        assert wait_for(lambda: _commanded(emu, began) > 50, timeout=10.0)
        assert emu.snapshot().current_state == 8
        pid = worker.pid
        assert pid is not None
        killed_at = time.monotonic()
        os.kill(pid, signal.SIGKILL)
        assert wait_for(lambda: emu.snapshot().watchdog_tripped_at is not None, timeout=2.0)
        got = follow(worker, until="lost", timeout=5)
        assert got.end is not None and got.end.status == "aborted"
    snap = emu.snapshot()
    assert snap.error & AXIS_ERROR_WATCHDOG_TIMER_EXPIRED
    assert snap.current_state == 1 and snap.applied_torque == 0.0
    tripped = snap.watchdog_tripped_at
    assert tripped is not None
    physics_step = 1.0 / EmulatorConfig().physics_rate
    # the last feed is the worker's last line: written before the kill, read by the device at
    # most a moment later (bytes in flight on the line)
    in_flight = snap.last_feed - killed_at
    assert in_flight < 0.05
    assert len(emu.torques_since(killed_at)) <= 1
    # zero torque exactly one watchdog timeout after the last command (to one physics step)
    assert timeout < tripped - snap.last_feed <= timeout + physics_step + 1e-9
    assert tripped - killed_at <= timeout + physics_step + max(0.0, in_flight) + 1e-9


def test_estop_reaches_the_device_within_two_periods_and_latches(rig):
    cfg, emu = rig
    with Worker(spec(emu), WorkerOptions()) as worker:
        worker.start()
        worker.start_session(cfg, "estop")
        began = follow(worker, until="session_started").of("session_started")[0].t
        # it was commanding torque (waited for, not slept on)
        assert wait_for(lambda: _commanded(emu, began) > 50, timeout=10.0)
        sent = worker.estop()
        got = follow(worker, timeout=10)
        assert got.end is not None and got.end.reason == "e-stop"
        after = emu.torques_since(sent)
        nonzero = [v for _, v in after if v != 0.0]
        assert len(nonzero) <= 2
        assert after and after[-1][1] == 0.0
        first_zero = next(i for i, (_, v) in enumerate(after) if v == 0.0)
        assert first_zero <= 2  # the zero is at most the third setpoint after the e-stop
        snap = emu.snapshot()
        assert snap.current_state == 1 and snap.applied_torque == 0.0
        worker.reset()
        follow(worker, until="reset")
        time.sleep(0.3)
        snap = emu.snapshot()
        assert snap.current_state == 1 and snap.applied_torque == 0.0  # nothing restarted
        assert [v for _, v in emu.torques_since(sent) if v != 0.0] == nonzero
