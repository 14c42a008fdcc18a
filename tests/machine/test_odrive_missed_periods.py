"""Missed periods on a free-running plant (issue 13.5): a worker paused mid-session (SIGSTOP,
then SIGCONT: as a host stalls it) catches up the periods it missed, within a bound, so the
loop's time and integrals are the plant's; a stall beyond the bound ends the session.

The plant is the emulated ODrive's, in its own process on its own clock: it keeps turning
while the worker is stopped, the drive holding the last torque. Truths, independent of the
loop: (1) the wall clock (every record's ``mono``, its cycle's start): the loop's time
``t = k·dt`` must keep within a period of it, k counting every period that passed; (2) the
plant's own angle, which is the integral of its velocity: ∫ w dt over the records must
equal q(end) - q(start). With the nominal dt and no catch-up, both lose the pause.
"""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest

from sessions.codes import FLAG_CATCHUP
from sessions.machine.odrive.emulator import EmulatorConfig, EmulatorProcess
from sessions.worker import Worker, WorkerOptions
from sessions.worker.ring import INDEX
from testing.live import follow, odrive, scenario

pytestmark = pytest.mark.realtime  # timed where it happens: alone, after the parallel rooms

RATE = 500.0  # Hz: the rate the pty link holds on a loaded VM (docs/live-machine.md)
DT = 1.0 / RATE


def _paused_session(pause: float, catch_up_max: float = 0.1, duration: float = 3.0):
    cfg = scenario(duration=duration, rate=RATE)
    with EmulatorProcess(EmulatorConfig.from_session(cfg)) as emu:
        spec = odrive(emu.path, reply_timeout=0.2, watchdog_timeout=0.5)
        # the pause must not look like a hung worker (100 ms) to the parent
        opt = WorkerOptions(heartbeat_timeout=1.5, catch_up_max=catch_up_max)
        with Worker(spec, opt) as worker:
            worker.start()
            reader = worker.open_reader()
            worker.start_session(cfg, "paused")
            follow(worker, until="session_started", timeout=30)
            time.sleep(1.0)  # the handle is moving: the seeker is out of its start delay
            pid = worker.pid
            assert pid is not None
            os.kill(pid, signal.SIGSTOP)
            stopped = time.monotonic()
            time.sleep(pause)
            os.kill(pid, signal.SIGCONT)
            paused = time.monotonic() - stopped
            got = follow(worker, reader, timeout=30)
            reader.close()
        snap = emu.snapshot()
    return got, paused, snap


def test_a_paused_worker_catches_up_and_keeps_the_plants_time():
    # a 60 ms pause against a 400 ms bound: a loaded host resumes the worker late (the
    # external CI saw 125 ms of stall for this 60 ms pause), and the bound is not what is
    # tested here; the next test holds it
    got, paused, _ = _paused_session(0.06, catch_up_max=0.4)
    end = got.end
    assert end is not None and end.status == "completed", end
    d = got.data
    assert got.missed == 0
    t, mono = d[:, INDEX["t"]], d[:, INDEX["mono"]]
    flags = d[:, INDEX["flags"]].astype(np.int64)
    # (1) the loop's clock is the wall clock: k counts every period that passed (a cycle
    # starts less than a period after its deadline, a caught-up one is dated at its deadline)
    lag = (mono - t)[:-1]
    assert np.ptp(lag) < DT, np.ptp(lag)
    # (2) the integral of w over the loop's time is the plant's own angle
    run = d[d[:, INDEX["phase"]] >= 0]
    q, w = run[:, INDEX["q"]], run[:, INDEX["w"]]
    integral = float(np.sum(0.5 * (w[1:] + w[:-1])) * DT)
    moved = float(q[-1] - q[0])
    assert moved > 3.0  # rad: it turned a good deal, ~0.1 rad of it during the pause
    assert integral == pytest.approx(moved, abs=0.02), (integral, moved)
    # the pause was caught up: one record per period missed, none skipped
    caught = flags & FLAG_CATCHUP != 0
    assert caught.sum() >= int(paused * RATE) - 1
    assert np.allclose(np.diff(t[:-1]), DT)  # every period, in order (the last: zero torque)
    # the torque recorded for a caught-up period is what the drive held: the last one written
    held = d[caught, INDEX["u_out"]]
    first = np.argmax(caught)
    assert held[0] == d[first - 1, INDEX["u_out"]]
    # and the duration was reached in the plant's time, not duration + pause: the closing
    # stop (the wind-down to rest) drives from period n + 1 of the loop's clock
    stop = next(s.stage for s in got.of("stage") if s.stage.kind == "stop")
    assert stop.start == pytest.approx(3.0 + DT, abs=DT / 2)


def test_a_stall_beyond_the_bound_ends_the_session_with_zero_torque():
    got, _, snap = _paused_session(0.25)  # > catch_up_max = 0.1 s
    end = got.end
    assert end is not None and end.status == "aborted"
    assert end.reason.startswith("the loop stalled ") and "catch_up_max = 100 ms" in end.reason
    assert float(end.reason.split("stalled ")[1].split(" ms")[0]) >= 240
    assert got.data[-1, INDEX["u_out"]] == 0.0
    assert snap.current_state == 1 and snap.applied_torque == 0.0
