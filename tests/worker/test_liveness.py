"""The parent notices a dead worker and a hung one, and reports the session aborted.

Real processes, real signals: SIGKILL (dead), SIGSTOP (hung: alive but not beating), SIGTERM
(asked to stop: zero torque, clean exit). The summary the parent reports for a lost session is
checked against the telemetry it followed in the ring.
"""

from __future__ import annotations

import os
import signal
import time

import pytest

from sessions.worker import Worker, WorkerError
from sessions.worker.ring import INDEX
from testing.live import follow, scenario, wait_for, worker_options
from testing.processes import exited

# the dead and hung worker's detection is timed where it happens: those two run alone, after
# the parallel rooms (marker realtime); SIGTERM and shutdown are not timed


def _start(duration: float = 30.0) -> tuple[Worker, object]:
    worker = Worker(options=worker_options())
    worker.start()
    reader = worker.open_reader()
    worker.start_session(scenario(duration=duration), "victim")
    follow(worker, until="session_started")
    return worker, reader


@pytest.mark.realtime
def test_dead_worker_means_an_aborted_session():
    worker, reader = _start()
    try:
        first = follow(worker, until="evaluation", timeout=20)
        pid = worker.pid
        assert pid is not None
        os.kill(pid, signal.SIGKILL)
        got = follow(worker, until="lost", timeout=10)
        end = got.end
        assert end is not None and end.status == "aborted" and end.session_id == "victim"
        assert end.reason.startswith("worker died") and "-9" in end.reason
        lost = got.of("lost")[0]
        assert lost.exitcode == -signal.SIGKILL
        assert got.kinds()[-2:] == ["session_ended", "lost"]
        # the summary comes from the telemetry the parent followed: check it against the ring
        batch = reader.read()  # type: ignore[attr-defined]
        assert batch.missed == 0
        run = batch.data[batch.column("phase") >= 0]
        t, w, tau, work = (run[:, INDEX[c]] for c in ("t", "w", "tau", "W"))
        assert end.summary.duration == pytest.approx(t[-1] + 0.001, abs=1e-9)
        assert end.summary.work == work[-1]
        assert end.summary.mean_power == pytest.approx(float((tau * w).mean()), rel=1e-9)
        assert end.summary.peak_power == pytest.approx(float((tau * w).max()), rel=1e-12)
        seen = len(first.of("evaluation")) + len(got.of("evaluation"))
        assert end.summary.evaluations == seen >= 1
        assert end.summary.optimum_w == run[-1, INDEX["gamma"]]
        assert end.summary.abort_reason == end.reason
        st = worker.status()
        assert st.state == "lost" and st.session_id is None and st.last_end == end
        with pytest.raises(WorkerError):
            worker.start_session(scenario(), "after")
    finally:
        reader.close()  # type: ignore[attr-defined]
        worker.shutdown()


@pytest.mark.realtime
def test_hung_worker_is_declared_lost_and_killed():
    worker, reader = _start()
    try:
        time.sleep(0.2)
        pid = worker.pid
        assert pid is not None
        os.kill(pid, signal.SIGSTOP)  # alive, but its heartbeat stops
        stopped_at = time.monotonic()
        got = follow(worker, until="lost", timeout=10)
        noticed = time.monotonic() - stopped_at
        end = got.end
        assert end is not None and end.status == "aborted"
        assert end.reason.startswith("worker unresponsive: no heartbeat for")
        assert int(end.reason.split("for ")[1].split(" ms")[0]) > 100
        assert noticed > 0.1  # never before the heartbeat timeout
        assert got.of("lost")[0].exitcode is None
        # it was killed: a hung worker must not come back to drive the motor
        assert wait_for(lambda: exited(pid), 5.0)
        last = reader.read()  # type: ignore[attr-defined]
        assert len(last) > 0  # the ring kept what the hung worker ran: check it, never skip
        assert end.summary.duration == pytest.approx(
            last.column("t")[last.column("phase") >= 0][-1] + 0.001, abs=0.01
        )
    finally:
        reader.close()  # type: ignore[attr-defined]
        worker.shutdown()


def test_sigterm_zeroes_and_exits_cleanly():
    worker, reader = _start()
    try:
        time.sleep(0.2)
        pid = worker.pid
        assert pid is not None
        os.kill(pid, signal.SIGTERM)
        got = follow(worker, until="lost", timeout=10)
        end = got.end
        assert end is not None and end.status == "aborted"
        assert "SIGTERM" in end.reason
        assert got.of("exited")[0].reason == "terminated (SIGTERM)"
        batch = reader.read()  # type: ignore[attr-defined]
        assert batch.data[-1, INDEX["u_out"]] == 0.0
        # it went when nobody here asked it to: lost (a reset replaces it), saying why
        lost = got.of("lost")[0]
        assert lost.reason == "worker exited: terminated (SIGTERM)" and lost.exitcode == 0
        assert got.kinds()[-2:] == ["exited", "lost"]  # its own end, then the verdict
        assert wait_for(lambda: worker.poll() == [] and worker.state == "lost", 5.0)
    finally:
        reader.close()  # type: ignore[attr-defined]
        worker.shutdown()


def test_shutdown_ends_a_running_session_and_removes_the_ring():
    worker, reader = _start()
    name = worker.ring_info.name
    proc = worker._proc
    events = worker.shutdown(timeout=5.0)
    last = reader.read().data[-1]  # type: ignore[attr-defined]
    reader.close()  # type: ignore[attr-defined]
    # the shutdown's zero-torque record: no flag (not an e-stop, a fault or a limit)
    assert last[INDEX["u_out"]] == 0.0 and last[INDEX["flags"]] == 0.0
    kinds = [e.kind for e in events]
    assert "session_ended" in kinds and kinds[-1] == "exited"
    end = next(e for e in events if e.kind == "session_ended")
    assert end.status == "stopped" and end.reason == "worker shut down"
    assert events[-1].reason == "shutdown"
    assert proc.exitcode == 0  # it ended itself, not terminated after the timeout
    assert worker.state == "closed"
    assert not os.path.exists(f"/dev/shm/{name}")
    assert worker.shutdown() == []  # idempotent
