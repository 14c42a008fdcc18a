"""Safety behaviours of the worker: e-stop, velocity limit, passivity, parent death.

Independent truths: for the sim backend, the ring's record of the torque written each cycle
and the monotonic time each cycle started, against the moment the parent sent the e-stop;
for the ODrive, the emulated device's own log of every torque setpoint it received and its
axis state. Counts of cycles, not durations, so a loaded machine cannot make them flaky.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from sessions.codes import FLAG_ESTOP, TORQUE_LIMIT
from sessions.machine.odrive.emulator import EmulatorConfig, EmulatorProcess
from sessions.simulation import run_simulation
from sessions.worker import Worker, WorkerError
from sessions.worker.messages import StartSession
from sessions.worker.ring import INDEX
from testing.cli import ROOT
from testing.live import (
    OVERSPEED,
    PASSIVITY_BREACH,
    STRONG,
    follow,
    scenario,
    wait_for,
    worker_options,
)
from testing.processes import exited


def _one_session(cfg, name: str):  # type: ignore[no-untyped-def]
    """``cfg`` run as session ``name`` on a worker of its own, followed to its end."""
    with Worker(options=worker_options()) as worker:
        worker.start()
        reader = worker.open_reader()
        worker.start_session(cfg, name)
        got = follow(worker, reader, timeout=20)
        reader.close()
    return got


def test_estop_zeroes_torque_within_two_periods_and_latches():
    with Worker(options=worker_options()) as worker:
        worker.start()
        reader = worker.open_reader()
        worker.start_session(scenario(duration=30.0), "estop")
        follow(worker, until="timing")
        sent = worker.estop()
        got = follow(worker, reader, timeout=10)
        d = got.data
        mono, u = d[:, INDEX["mono"]], d[:, INDEX["u_out"]]
        before = d[mono < sent]
        assert np.count_nonzero(before[-200:, INDEX["u_out"]]) > 150  # it was pushing
        after = mono >= sent
        # cycles that started after the e-stop was sent and still wrote torque: at most 2
        assert np.count_nonzero(u[after]) <= 2
        assert int(d[-1, INDEX["flags"]]) & FLAG_ESTOP and u[-1] == 0.0
        estop = got.of("estop")[0]
        zero_at = estop.zero_at
        assert zero_at >= sent
        assert estop.session_id == "estop" and sent <= estop.t == zero_at  # whose, and when
        assert len(d[(mono > sent) & (mono < zero_at)]) <= 2  # cycles between: at most 2
        end = got.end
        assert end is not None and end.status == "stopped" and end.reason == "e-stop"
        assert end.state_after == "estopped" and worker.state == "estopped"
        with pytest.raises(WorkerError, match="estopped"):
            worker.start_session(scenario(), "refused")
        head = reader.head
        worker.reset()
        follow(worker, until="reset")
        assert worker.state == "idle"
        time.sleep(0.3)
        assert reader.head == head  # a reset runs nothing: not one cycle
        worker.start_session(scenario(duration=0.3), "after-reset")  # an explicit start does
        assert follow(worker).end.status == "completed"  # type: ignore[union-attr]
        reader.close()


def test_a_start_or_a_reset_during_a_session_is_refused_by_the_worker_itself():
    # The handle refuses a second start first; the worker must refuse it too (another
    # parent, a race): the command is answered, named, timed, and the session goes on.
    with Worker(options=worker_options()) as worker:
        worker.start()
        reader = worker.open_reader()
        worker.start_session(scenario(duration=1.0), "first")
        follow(worker, until="timing")
        asked = time.monotonic()
        worker._send(StartSession(scenario(duration=1.0), "second"))  # past the handle
        worker.reset()  # never clears anything while a session runs
        got = follow(worker, reader, timeout=20)
        reader.close()
    answered = [(r.command, r.reason) for r in got.of("rejected")]
    assert answered == [
        ("start", "a session is running"),
        ("reset", "a session is running; stop it first"),
    ]
    assert all(asked <= r.t <= got.end.t for r in got.of("rejected"))  # type: ignore[union-attr]
    assert got.end is not None and got.end.status == "completed"
    assert got.end.session_id == "first" and got.of("session_started") == []


def test_estop_while_idle_latches_too():
    with Worker(options=worker_options()) as worker:
        worker.start()
        worker.estop()
        follow(worker, until="estop")
        assert worker.state == "estopped"
        with pytest.raises(WorkerError):
            worker.start_session(scenario(), "x")
        worker.reset()
        follow(worker, until="reset")
        assert worker.state == "idle"


def test_velocity_over_the_limit_is_a_controlled_stop():
    # a strong person against a weak RISE controller overshoots 4 rad/s in ~75 ms
    cfg = scenario(**OVERSPEED)
    got = _one_session(cfg, "overspeed")
    end = got.end
    assert end is not None and end.status == "aborted"
    assert end.reason.startswith("velocity over the limit")
    assert [e.limit for e in got.of("limit")][:1] == ["velocity"]
    assert end.summary.duration < 0.5
    d = got.data
    stop = d[d[:, INDEX["phase"]] < 0]
    assert len(stop) > 0
    assert np.all(stop[:, INDEX["u_out"]] * stop[:, INDEX["w"]] <= 0.0)  # brakes, never drives
    # the governor keeps braking during the stop: a person pushing 20 N·m is held within its
    # span (full braking torque 0.5 rad/s over the limit), and the stop ends at zero torque
    assert np.all(np.abs(stop[:, INDEX["w"]]) <= 4.0 + 0.5)
    assert stop[-1, INDEX["u_out"]] == 0.0
    assert len(stop) <= (0.5 + 2.0) * 1000 + 1  # ramp, then at most the grace period


def test_a_person_stronger_than_the_motor_is_a_torque_limit_event_from_the_first_period():
    # controller A from rest: u = J·ad + J·k·e − τ, here −30 N·m against a 20 N·m motor on the
    # very first period; the limit event says so once, at that period's time
    cfg = scenario(**STRONG)
    got = _one_session(cfg, "strong")
    d = got.data[got.data[:, INDEX["phase"]] >= 0]
    clamped = (d[:, INDEX["flags"]].astype(int) & TORQUE_LIMIT) != 0
    assert clamped[0] and abs(d[0, INDEX["u_out"]]) == 20.0  # clamped from the first period
    torque = [e for e in got.of("limit") if e.limit == "torque"]
    assert len(torque) == 1 + int(np.count_nonzero(np.diff(clamped.astype(int)) == 1))
    assert torque[0].session_t == d[0, INDEX["t"]] and torque[0].value == 20.0
    assert torque[0].session_id == "strong"


def test_passivity_breach_stops_the_session_at_the_first_breach():
    # next to no person on the handle and a hard acceleration to 5 rad/s: during the transient
    # the observer's τ̂ (28) runs behind, and W(t) from τ̂·w dips below -c² = -1 mJ
    cfg = scenario(**PASSIVITY_BREACH)
    ref = run_simulation(cfg)
    breach = int(np.argmax(ref.column("W") < -1e-3))
    assert breach > 0  # the offline run breaches too, at this step
    got = _one_session(cfg, "passive")
    end = got.end
    assert end is not None and end.status == "aborted"
    assert end.reason.startswith("passivity breached")
    assert end.summary.passivity_min < -1e-3
    assert "passivity" in [e.limit for e in got.of("limit")]
    assert {e.session_id for e in got.of("limit")} | {e.session_id for e in got.of("stopping")} == {
        "passive"
    }  # the events name their session
    run = got.data[got.data[:, INDEX["phase"]] >= 0]
    assert len(run) == breach + 1  # stopped on the very step W crossed -c²
    assert run[-1, INDEX["W"]] == ref.column("W")[breach]
    stop = got.data[got.data[:, INDEX["phase"]] < 0]
    assert np.all(stop[:, INDEX["u_out"]] * stop[:, INDEX["w"]] <= 0.0)


PARENT = textwrap.dedent(
    """
    import sys, time
    from sessions.worker import Worker, WorkerOptions
    from testing.live import odrive, scenario
    if __name__ == "__main__":
        limits = {"reply_timeout": 0.2, "watchdog_timeout": 0.5}
        spec = odrive(sys.argv[1], **limits)
        worker = Worker(spec, WorkerOptions())
        worker.start()
        worker.start_session(scenario(duration=60.0), "orphan")
        while not any(e.kind == "session_started" for e in worker.poll()):
            time.sleep(0.01)
        print(worker.pid, flush=True)
        time.sleep(600)
    """
)


@pytest.mark.realtime  # a session over the emulated drive's pty: alone, after the parallel rooms
def test_parent_death_zeroes_the_torque_and_ends_the_worker():
    with EmulatorProcess(EmulatorConfig()) as emu:
        parent = subprocess.Popen(
            [sys.executable, "-c", PARENT, emu.path],
            stdout=subprocess.PIPE,
            text=True,
            cwd=ROOT,  # (the script imports testing.live from the checkout)
        )
        try:
            worker_pid = int(parent.stdout.readline())  # type: ignore[union-attr]
            time.sleep(0.3)
            assert emu.snapshot().current_state == 8
            killed_at = time.monotonic()
            os.kill(parent.pid, signal.SIGKILL)
            parent.wait(10)
            assert wait_for(lambda: exited(worker_pid), timeout=5.0)
            snap = emu.snapshot()
            assert snap.applied_torque == 0.0 and snap.input_torque == 0.0
            assert snap.current_state == 1
            # the worker itself zeroed and idled the drive: the watchdog never had to
            assert snap.error == 0 and snap.watchdog_tripped_at is None
            assert not snap.watchdog_enabled
            late = emu.torques_since(killed_at)
            assert late and late[-1][1] == 0.0
        finally:
            if parent.poll() is None:
                parent.kill()
                parent.wait(5)
