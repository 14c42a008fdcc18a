"""A worker that dies, however it dies, is noticed: its session ends aborted with the
telemetry it produced, the handle says lost (with why), and nothing is sent into the void.

Real processes and real faults through the simulator's fault injection (:class:`SimFault`):
the worker aborts on its own (SIGABRT, no goodbye), exits the way an unhandled bug makes it
exit (its last words sent), or is killed and then sent a command (a broken pipe).
"""

from __future__ import annotations

import os
import signal

import pytest

from sessions.machine import MachineSpec, SimFault
from sessions.worker import Worker, WorkerError, WorkerOptions
from sessions.worker.ring import INDEX
from testing.live import follow, scenario, wait_for
from testing.processes import exited


def _faulty_worker(kind: str, at: float = 0.5) -> Worker:
    # which death it was, not the watchdog (tests/worker/test_liveness.py): a worker starved of
    # the CPU for the default 0.1 s between its fault and its goodbye would read as a hang
    options = WorkerOptions(heartbeat_timeout=2.0)
    worker = Worker(MachineSpec(kind="sim", sim_fault=SimFault(kind=kind, at=at)), options)
    worker.start()
    return worker


@pytest.mark.parametrize(
    ("kind", "exitcode", "words"),
    [("worker-abort", -signal.SIGABRT, "worker died"), ("worker-exit", 0, "worker exited")],
)
def test_a_worker_dying_on_its_own_is_lost_and_its_session_aborted(kind, exitcode, words):
    worker = _faulty_worker(kind)
    reader = worker.open_reader()
    try:
        worker.start_session(scenario(duration=30.0), "victim")
        got = follow(worker, reader, until="lost", timeout=20)
        end = got.end
        assert end is not None and end.session_id == "victim" and end.status == "aborted"
        assert end.reason.startswith(words), end.reason
        if kind == "worker-exit":
            assert "injected fault worker-exit" in end.reason  # the worker's own last words
        lost = got.of("lost")[0]
        assert lost.exitcode == exitcode and lost.reason == end.reason
        assert got.kinds()[-2:] == ["session_ended", "lost"]
        # its data: every period up to the fault, summarised from what the parent followed
        run = got.data[got.data[:, INDEX["phase"]] >= 0]
        assert len(run) == 500  # 0.5 s at 1 kHz: the fault hit on the 501st read
        assert end.summary.duration == pytest.approx(0.5)
        st = worker.status()
        assert st.state == "lost" and st.fault == end.reason and st.session_id is None
        with pytest.raises(WorkerError, match="lost"):
            worker.start_session(scenario(), "after")
    finally:
        reader.close()
        worker.shutdown()


def test_a_command_to_a_dead_worker_finds_it_lost():
    worker = _faulty_worker("worker-exit", at=1000.0)  # never reached
    try:
        worker.start_session(scenario(duration=30.0), "victim")
        follow(worker, until="evaluation", timeout=20)
        pid = worker.pid
        assert pid is not None
        os.kill(pid, signal.SIGKILL)
        assert wait_for(lambda: exited(pid, threads=True), 5.0)
        # no poll in between: the command itself finds the pipe broken
        with pytest.raises(WorkerError, match=r"lost .*reset"):
            worker.stop()
        assert worker.state == "lost"
        got = follow(worker, until="lost", timeout=5)
        assert got.end is not None and got.end.status == "aborted"
        assert got.end.reason.startswith("worker died")
        with pytest.raises(WorkerError, match="lost"):
            worker.estop()
    finally:
        worker.shutdown()
