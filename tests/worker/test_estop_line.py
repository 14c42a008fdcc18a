"""The e-stop line (issue 12.2): a stamp in the ring's header that the worker looks at every
period, before its command pipe. Nothing queued in the pipe delays it, and any process that
holds the ring's name (the web server's e-stop gate) can pull it. Independent truth: the
ring's own records (torque written, the cycle's CLOCK_MONOTONIC) against the moment of the
request; counts of cycles, not durations."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest

from sessions.codes import FLAG_ESTOP
from sessions.worker import Worker, WorkerOptions
from sessions.worker.ring import INDEX
from testing.cli import ROOT
from testing.live import follow, scenario

# the count starts at a clock stamp taken just before the line is pulled: on a machine loaded
# by other tests the puller can be preempted between the two, so this runs alone (realtime)
pytestmark = pytest.mark.realtime


def _cycles_after(d: np.ndarray, sent: float) -> int:
    """Cycles that started after ``sent`` and still wrote torque."""
    mono, u = d[:, INDEX["mono"]], d[:, INDEX["u_out"]]
    return int(np.count_nonzero(u[mono >= sent]))


def test_an_estop_is_not_queued_behind_the_command_pipe() -> None:
    with Worker(options=WorkerOptions()) as worker:
        worker.start()
        reader = worker.open_reader()
        worker.start_session(scenario(duration=30.0), "busy-pipe")
        follow(worker, until="timing")
        for _ in range(400):  # commands the worker answers one per period, all refused
            worker.reset()
        sent = worker.estop()
        got = follow(worker, reader, timeout=20)
        d = got.data
        assert int(d[-1, INDEX["flags"]]) & FLAG_ESTOP and d[-1, INDEX["u_out"]] == 0.0
        assert _cycles_after(d, sent) <= 2  # not 400 periods behind the resets
        assert got.end is not None and got.end.reason == "e-stop"
        assert worker.state == "estopped"
        reader.close()


def test_another_process_pulls_the_line() -> None:
    with Worker(options=WorkerOptions()) as worker:
        worker.start()
        reader = worker.open_reader()
        worker.start_session(scenario(duration=30.0), "other")
        follow(worker, until="timing")
        code = textwrap.dedent(
            f"""
            import time
            from sessions.worker.ring import EStopLine
            line = EStopLine({worker.ring_info.name!r})
            print(time.monotonic(), flush=True)
            line.trigger()
            line.close()
            """
        )
        out = subprocess.run(
            [sys.executable, "-c", code],
            check=False,
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert out.returncode == 0, out.stderr
        sent = float(out.stdout.split()[0])
        got = follow(worker, reader, timeout=20)
        d = got.data
        assert int(d[-1, INDEX["flags"]]) & FLAG_ESTOP and d[-1, INDEX["u_out"]] == 0.0
        assert _cycles_after(d, sent) <= 2
        assert worker.state == "estopped"
        # a reset clears the latch; the line stays quiet until pulled again
        worker.reset()
        follow(worker, until="reset")
        assert worker.state == "idle"
        worker.start_session(scenario(duration=0.3), "after")
        assert follow(worker).end.status == "completed"  # type: ignore[union-attr]
        reader.close()
