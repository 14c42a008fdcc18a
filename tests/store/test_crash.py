"""Crash safety: a writer process killed with SIGKILL in the middle of a session, then the
store reopened as the server does on start (on a real SQLite file, and on PostgreSQL)."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest

from sessions.store import codec, open_server_store
from sessions.store.database import sqlite_path
from testing.cli import ROOT
from testing.store import FAST_HASHER, telemetry
from testing.store_writer import evaluation

LOSS = 1.0  # at most this much data (seconds) may be lost


def _kill_writer(url: str, after: float) -> tuple[int, float]:
    """Run the writer, SIGKILL it ``after`` seconds into feeding; the session id and the
    newest time it had handed to the recorder when it died (the writer's own record of it:
    on a loaded machine a stalled writer feeds less than the wall clock since its start)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    fd, progress = tempfile.mkstemp(prefix="fed-", suffix=".txt")
    os.close(fd)
    proc = subprocess.Popen(
        [sys.executable, "-m", "testing.store_writer", url, progress],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        if not line:
            pytest.fail(f"writer did not start: {proc.stderr.read() if proc.stderr else ''}")
        hello = json.loads(line)
        while time.monotonic() < hello["start"] + after:
            assert proc.poll() is None, "writer ended early"
            time.sleep(0.001)
        os.kill(proc.pid, signal.SIGKILL)
        wall = time.monotonic() - hello["start"]
        assert proc.wait(timeout=10) == -signal.SIGKILL
        lines = Path(progress).read_text().split()
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate()
        os.unlink(progress)
    fed_for = float(lines[-1]) if lines else -0.001
    assert fed_for <= wall + 1e-9  # (never ahead of the clock: sample k fed after k ms)
    return hello["session"], fed_for


def _check_recovered(url: str, sid: int, fed_for: float) -> None:
    store, aborted = open_server_store(url, password_hasher=FAST_HASHER)
    try:
        assert aborted == [sid]
        s = store.sessions.get(sid)
        assert (s.status, s.abort_reason) == ("aborted", "server restarted")
        assert store.check() == []
        data = store.telemetry.load(sid)
        n = len(data)
        stored_until = float(data.column("t")[-1]) if n else -0.001
        assert fed_for - LOSS <= stored_until <= fed_for + 1e-9, (stored_until, fed_for)
        # exactly the samples fed, in order, none missing
        np.testing.assert_array_equal(data.columns, codec.quantize(telemetry(60.0)[:n].T))
        assert s.duration == pytest.approx(stored_until + 0.001 if n else 0.0)
        assert s.ended_at == s.started_at + timedelta(seconds=s.duration)
        evs = store.sessions.evaluations(sid)
        expected = [evaluation(k) for k in range(len(evs))]
        assert [(e.t, e.candidate, e.power, e.stderr) for e in evs] == [
            (e.t, e.candidate, e.power, e.stderr) for e in expected
        ]
        due = fed_for - LOSS  # everything fed up to then must be stored
        assert len(evs) >= sum(1 for k in range(400) if evaluation(k).t <= due)
        assert s.evaluation_count == len(evs)
        events = store.sessions.events(sid)
        assert [e.detail["n"] for e in events] == list(range(len(events)))
        assert len(events) >= sum(1 for k in range(60) if k <= due)
        assert store.sessions.recover() == []
    finally:
        store.close()


@pytest.mark.parametrize("after", [0.05, 0.6, 1.37, 2.05])
def test_sigkill_mid_session_sqlite(tmp_path: Path, after: float) -> None:
    url = f"sqlite:///{tmp_path / 'crash.sqlite3'}"
    sid, fed_for = _kill_writer(url, after)
    path = sqlite_path(url)
    assert path is not None and path.exists()
    _check_recovered(url, sid, fed_for)
    with sqlite3.connect(path) as conn:  # independent of the store's own check
        assert conn.execute("PRAGMA integrity_check").fetchall() == [("ok",)]
        assert conn.execute("PRAGMA journal_mode").fetchone() == ("wal",)


def test_sigkill_mid_session_postgresql(pg_url: str) -> None:
    sid, fed_for = _kill_writer(pg_url, 1.61)
    _check_recovered(pg_url, sid, fed_for)
