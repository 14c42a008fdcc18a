"""The recorder's promises that test_telemetry.py leaves open: a failed commit loses nothing
(even with data fed while it failed), events are committed at once, the live summary continues
over a resumed session and follows only its own session, single rows are checked as strictly
as batches, the thread idles when there is nothing to write and never keeps a process alive.
Figures are checked against numpy over the rows fed (an independent computation)."""

from __future__ import annotations

import contextlib
import logging
import math
import os
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy.exc import IntegrityError

from sessions.config import parse_session_config
from sessions.seekers import Evaluation
from sessions.store import Store, StoreError, StoreValueError, open_store
from sessions.store.recorder import LiveStats
from sessions.summary import SessionSummary
from sessions.telemetry import INDEX, WIDTH
from testing.store import FAST_HASHER, telemetry

ROOT = Path(__file__).resolve().parents[2]
CFG = parse_session_config({"duration": 600.0})


def running(store: Store, cfg: object = CFG) -> int:
    user = store.users.create("Rita")
    return store.sessions.start(user.id, cfg).id


def live(rows: np.ndarray, rate: float = 1000.0) -> dict[str, float]:
    """The live summary of ``rows``, computed here: mean and peak τ·w, W at the end, min W."""
    p = rows[:, INDEX["tau"]] * rows[:, INDEX["w"]]
    work = rows[:, INDEX["W"]]
    return {
        "duration": rows[-1, 0] + 1.0 / rate,
        "mean_power": p.mean(),
        "peak_power": max(0.0, p.max()),
        "work": work[-1],
        "passivity_min": min(0.0, work.min()),
    }


def assert_live(store: Store, sid: int, rows: np.ndarray, rate: float = 1000.0) -> None:
    rec = store.sessions.get(sid)
    for name, want in live(rows, rate).items():
        assert getattr(rec, name) == pytest.approx(want, rel=1e-9, abs=1e-12), name


def wait_for(cond, timeout: float = 10.0) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, "condition not met in time"
        time.sleep(0.01)


@pytest.fixture
def sqlite_store(tmp_path: Path):  # type: ignore[no-untyped-def]
    """A store in a SQLite file (the tests that reach into the database with SQLite's own
    tools: a trigger that makes commits fail, a second writer that holds the lock)."""
    path = tmp_path / "rec.sqlite3"
    st = open_store(f"sqlite:///{path}", password_hasher=FAST_HASHER)
    try:
        yield st, path
    finally:
        st.close()


def fail_events(path: Path, on: bool) -> None:
    """A real database fault: inserting an event aborts the transaction (SQLite trigger)."""
    with sqlite3.connect(path) as con:
        if on:
            con.execute(
                "CREATE TRIGGER refuse BEFORE INSERT ON events "
                "BEGIN SELECT RAISE(ABORT, 'disk says no'); END"
            )
        else:
            con.execute("DROP TRIGGER refuse")


def test_a_failed_commit_keeps_everything_for_the_next(sqlite_store) -> None:  # type: ignore[no-untyped-def]
    store, path = sqlite_store
    sid = running(store)
    rec = store.recorder(sid, background=False, flush_interval=1.0)
    rows = telemetry(0.5)
    fail_events(path, on=True)
    rec.add_rows(rows[:300])  # (an inline recorder may commit these on its own: no event)
    rec.add_evaluation(Evaluation(0.2, 3.0, 6.0, 0.1))
    with pytest.raises(IntegrityError, match="disk says no"):
        rec.add_event(0.25, "limit", {"what": "torque"})  # an event is committed at once
    assert rec.error is not None and "disk says no" in str(rec.error)
    assert store.sessions.events(sid) == []
    with contextlib.suppress(IntegrityError):  # a retry once the interval passed fails too
        rec.add_rows(rows[300:])
    with contextlib.suppress(IntegrityError):
        rec.add_evaluation(Evaluation(0.4, 3.5, 6.5))
    with pytest.raises(IntegrityError, match="disk says no"):
        rec.flush()  # still failing: everything kept, in order
    flushes = rec.flushes
    fail_events(path, on=False)
    rec.flush()
    assert rec.error is None and rec.flushes == flushes + 1
    np.testing.assert_array_equal(store.telemetry.load(sid).column("t"), rows[:, 0])
    assert [(e.t, e.candidate) for e in store.sessions.evaluations(sid)] == [(0.2, 3.0), (0.4, 3.5)]
    assert [(e.t, e.kind, e.detail) for e in store.sessions.events(sid)] == [
        (0.25, "limit", {"what": "torque"})
    ]
    assert store.sessions.get(sid).evaluation_count == 2
    assert_live(store, sid, rows)
    rec.finish("completed")


def test_data_fed_while_a_commit_waits_on_a_lock_is_kept(sqlite_store, caplog) -> None:  # type: ignore[no-untyped-def]
    """Another writer holds the database past the busy timeout: the recorder's commit fails
    (logged, retried) and what was fed meanwhile is kept with what failed, in order."""
    store, path = sqlite_store
    sid = running(store)
    rec = store.recorder(sid, flush_interval=0.1)
    rows = telemetry(0.6)
    holder = sqlite3.connect(path, isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")  # the write lock, held
    try:
        caplog.set_level(logging.WARNING, logger="sessions.store.recorder")
        rec.add_rows(rows[:200])
        rec.add_evaluation(Evaluation(0.1, 3.0, 6.0))
        time.sleep(0.5)  # a flush has begun and waits on the lock
        rec.add_rows(rows[200:400])  # fed while it waits
        rec.add_evaluation(Evaluation(0.3, 3.2, 6.2))
        rec.add_event(0.3, "note", {"n": 1})
        wait_for(lambda: rec.error is not None, timeout=30.0)
    finally:
        holder.rollback()
        holder.close()
    rec.add_rows(rows[400:])
    rec.close()
    assert rec.error is None
    np.testing.assert_array_equal(store.telemetry.load(sid).column("t"), rows[:, 0])
    assert [e.t for e in store.sessions.evaluations(sid)] == [0.1, 0.3]
    assert [e.kind for e in store.sessions.events(sid)] == ["note"]
    assert_live(store, sid, rows)
    warned = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert warned, "the failed flush is logged"
    msg = warned[0].getMessage()
    assert msg.startswith(f"session {sid}: flush failed, will retry: ") and "locked" in msg


def test_an_event_fed_during_a_commit_is_committed_right_after_it(sqlite_store, caplog) -> None:  # type: ignore[no-untyped-def]
    """Rows wait for the interval (a commit a second, not one per row); an event never waits:
    fed while the thread's commit waits on another writer, it is committed right after that
    commit, not an interval later. The commit that waited takes the write lock first (BEGIN
    IMMEDIATE), so the other writer's commit meanwhile does not make it fail."""
    store, path = sqlite_store
    sid = running(store)
    interval = 1.0
    rec = store.recorder(sid, flush_interval=interval)
    caplog.set_level(logging.WARNING, logger="sessions.store.recorder")
    rec.add_rows(telemetry(0.2))
    time.sleep(0.3)
    assert rec.flushes == 0 and store.telemetry.span(sid).samples == 0  # kept for the interval
    holder = sqlite3.connect(path, isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")  # another writer, holding the lock
    holder.execute("CREATE TABLE other_writer (x)")
    try:
        rec.add_event(0.1, "first", {})  # the thread's commit begins, and waits on the lock
        wait_for(rec._flush_lock.locked)
        rec.add_event(0.2, "second", {})  # fed while it waits
        time.sleep(0.1)
        holder.execute("COMMIT")  # the other writer's data goes in first
    finally:
        holder.close()
    seen: dict[int, float] = {}  # events committed -> when first seen
    deadline = time.monotonic() + 10.0
    while len(seen) < 2 or max(seen) < 2:
        seen.setdefault(len(store.sessions.events(sid)), time.monotonic())
        assert time.monotonic() < deadline, f"events seen: {seen}"
        time.sleep(0.005)
    first = seen.get(1, seen[2])
    assert seen[2] - first < interval / 2  # right after, not at the next interval
    assert [e.kind for e in store.sessions.events(sid)] == ["first", "second"]
    assert rec.error is None and store.telemetry.span(sid).samples == 200
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]  # nothing failed
    rec.close()


def test_a_recorder_whose_session_ended_elsewhere_says_so_and_stops(store: Store, caplog) -> None:  # type: ignore[no-untyped-def]
    sid = running(store)
    rec = store.recorder(sid, flush_interval=0.05)
    rec.add_rows(telemetry(0.1))
    wait_for(lambda: rec.flushes == 1)
    store.sessions.finish(sid, "aborted", abort_reason="operator")
    caplog.set_level(logging.ERROR, logger="sessions.store.recorder")
    rec.add_rows(telemetry(0.1, t0=0.1))
    wait_for(lambda: rec.error is not None)
    assert rec._thread is not None
    rec._thread.join(timeout=5)
    assert not rec._thread.is_alive()  # no point retrying
    msgs = [r.getMessage() for r in caplog.records if r.levelno == logging.ERROR]
    assert msgs == [f"session {sid}: recording stopped: session {sid} is no longer running"]


def test_an_event_is_committed_at_once(store: Store) -> None:
    sid = running(store)
    inline = store.recorder(sid, background=False, flush_interval=1.0)
    inline.add_event(0.0, "start", {})
    assert [e.kind for e in store.sessions.events(sid)] == ["start"]  # no flush() called
    inline.close()
    rec = store.recorder(sid, flush_interval=1.0)
    time.sleep(0.05)  # the thread waits for its interval
    began = time.monotonic()
    rec.add_event(0.5, "estop", {"by": "trainer"})
    wait_for(lambda: len(store.sessions.events(sid)) == 2, timeout=5.0)
    assert time.monotonic() - began < 0.6  # not after the 1 s interval
    rec.close()


def test_the_thread_idles_and_counts_its_commits(store: Store) -> None:
    sid = running(store)
    rec = store.recorder(sid, flush_interval=0.05)
    cpu0 = time.process_time()
    time.sleep(1.0)
    assert time.process_time() - cpu0 < 0.3  # waiting, not spinning
    assert rec.flushes == 0  # nothing fed: no commit
    rec.add_rows(telemetry(0.1))
    wait_for(lambda: rec.flushes == 1)
    time.sleep(0.2)
    assert rec.flushes == 1
    rec.close()
    assert rec.flushes == 1  # nothing left to commit at close


def test_an_inline_recorder_commits_once_its_interval_passed(store: Store) -> None:
    sid = running(store)
    rec = store.recorder(sid, background=False, flush_interval=1.0)
    rec.add_rows(telemetry(0.1))
    assert rec.flushes == 0 and store.telemetry.span(sid).samples == 0
    time.sleep(1.05)
    rec.add_rows(telemetry(0.1, t0=0.1))
    assert rec.flushes == 1 and store.telemetry.span(sid).samples == 200
    rec.add_evaluation(Evaluation(0.2, 3.0, 5.0))
    assert rec.flushes == 1
    rec.close()
    assert rec.flushes == 2


def test_a_resumed_session_continues_its_live_summary(store: Store) -> None:
    sid = running(store)
    rows = telemetry(2.5)
    first = store.recorder(sid, background=False)
    first.add_rows(rows[:1500])
    first.close()
    assert_live(store, sid, rows[:1500])
    second = store.recorder(sid, background=False)
    second.add_event(1.6, "resumed", {})  # a commit without telemetry changes no figure
    assert_live(store, sid, rows[:1500])
    second.add_rows(rows[1500:])
    second.flush()
    assert_live(store, sid, rows)
    assert second.stored_until == rows[-1, 0]


def test_evaluations_and_events_before_any_telemetry(store: Store) -> None:
    sid = running(store)
    rec = store.recorder(sid, background=False)
    rec.add_evaluations([Evaluation(0.0, 2.0, 4.0), Evaluation(0.0, 2.5, 4.5, math.inf)])
    rec.flush()
    got = store.sessions.get(sid)
    assert got.evaluation_count == 2 and got.duration == 0.0 and got.mean_power == 0.0
    assert [e.stderr for e in store.sessions.evaluations(sid)] == [0.0, None]
    rec.add_event(0.0, "armed", {"ok": True})
    assert store.telemetry.span(sid).samples == 0
    rec.add_rows(telemetry(0.2))
    rec.flush()
    assert_live(store, sid, telemetry(0.2))
    assert store.sessions.get(sid).evaluation_count == 2
    rec.close()


def test_finish_keeps_the_engines_summary_and_the_reason(store: Store) -> None:
    sid = running(store)
    rec = store.recorder(sid, background=False)
    rec.add_rows(telemetry(0.3))
    summary = SessionSummary(
        optimum_w=3.1, optimum_p=7.0, converged=True, seeker="brent", mean_power=6.0,
        peak_power=9.0, work=1.5, duration=0.3, passivity_min=-0.5, evaluations=4,
    )  # fmt: skip
    done = rec.finish("completed", summary)
    assert done.summary() == summary.model_copy(update={"abort_reason": None})
    other = running(store)
    rec = store.recorder(other, background=False)
    rec.add_rows(telemetry(0.3))
    done = rec.finish("aborted", abort_reason="the handle jammed")
    assert done.status == "aborted" and done.abort_reason == "the handle jammed"
    assert done.duration == pytest.approx(0.3)  # the live figures became the summary


def test_single_rows_are_checked_like_batches(store: Store) -> None:
    sid = running(store)
    rec = store.recorder(sid, background=False)
    rows = telemetry(0.01)
    bad_first = [math.nan, -0.001, math.inf, None]
    for t in bad_first:
        with pytest.raises(StoreValueError) as info:
            rec.add_row((t, *rows[0, 1:]))
        assert info.value.field.startswith("telemetry"), t
    with pytest.raises(StoreValueError) as info:
        rec.add_row(tuple(rows[0, :-1]))
    assert info.value.field == "telemetry"
    rec.add_row(tuple(rows[0]))  # t = 0 is a valid first sample
    rec.add_row(tuple(rows[1]))
    for again in (rows[1], rows[0]):  # the same time, or earlier
        with pytest.raises(StoreValueError, match="not after the last sample"):
            rec.add_row(tuple(again))
    rec.flush()
    rec.add_row(tuple(rows[2]))  # after a flush, rows are still taken
    with pytest.raises(StoreValueError, match="not after the last sample"):
        rec.add_rows(rows[2:5])  # a batch starting at the last time
    rec.add_rows(rows[3:4])  # a batch of one
    rec.add_rows(np.empty((0, WIDTH)))  # and of none
    rec.close()
    np.testing.assert_array_equal(store.telemetry.load(sid).column("t"), rows[:4, 0])
    with pytest.raises(StoreError, match="closed"):
        rec.add_row(tuple(rows[4]))


def test_the_flush_interval_is_checked(store: Store) -> None:
    sid = running(store)
    for bad in (0.0, -1.0, 1.5):
        with pytest.raises(StoreValueError) as info:
            store.recorder(sid, flush_interval=bad)
        assert info.value.field == "flush_interval"
    store.recorder(sid, flush_interval=1.0, background=False).close()


def test_the_duration_follows_the_sessions_rate(store: Store) -> None:
    sid = running(store, parse_session_config({"duration": 60.0, "rate": 500.0}))
    rows = telemetry(0.4, rate=500.0)
    rec = store.recorder(sid, background=False)
    rec.add_rows(rows)
    rec.flush()
    assert_live(store, sid, rows, rate=500.0)
    assert store.sessions.get(sid).duration == pytest.approx(0.4)
    rec.close()


def test_two_sessions_record_side_by_side(store: Store) -> None:
    a, b = running(store), running(store)
    ra, rb = store.recorder(a, background=False), store.recorder(b, background=False)
    ra.add_rows(telemetry(0.3))
    ra.flush()
    assert store.sessions.get(b).duration == 0.0  # b's summary is b's
    rb.add_rows(telemetry(0.1))
    rb.flush()
    assert_live(store, a, telemetry(0.3))
    assert_live(store, b, telemetry(0.1))
    ra.close()
    rb.close()


def test_live_stats_of_one_sample_and_of_no_finite_power() -> None:
    one = telemetry(0.001)
    stats = LiveStats().add(one.T.copy())
    p = one[0, INDEX["tau"]] * one[0, INDEX["w"]]
    assert (stats.count, stats.power_sum, stats.t_last) == (1, p, 0.0)
    assert stats.peak == max(0.0, p)
    nan = one.copy()
    nan[:, INDEX["tau"]] = math.nan
    nan[:, INDEX["W"]] = math.nan
    nan[:, 0] = 0.001
    after = stats.add(nan.T.copy())
    assert (after.count, after.power_sum, after.peak) == (1, p, stats.peak)
    assert (after.work, after.work_min, after.t_last) == (stats.work, stats.work_min, 0.001)
    assert LiveStats().columns(0.001) == {
        "duration": 0.0, "mean_power": 0.0, "peak_power": 0.0, "work": 0.0, "passivity_min": 0.0,
    }  # fmt: skip


def test_an_open_recorder_never_keeps_a_process_alive(tmp_path: Path) -> None:
    """The thread is a daemon: a program that exits without close() still exits (what it fed
    within the last interval may be lost; what came before is stored)."""
    url = f"sqlite:///{tmp_path / 'exit.sqlite3'}"
    code = (
        "import sys, time\n"
        "from sessions.config import parse_session_config\n"
        "from sessions.store import open_store\n"
        "from testing.store import telemetry\n"
        "st = open_store(sys.argv[1])\n"
        "sid = st.sessions.start(st.users.create('X').id, parse_session_config({})).id\n"
        "rec = st.recorder(sid, flush_interval=0.05)\n"
        "rec.add_rows(telemetry(0.2))\n"
        "time.sleep(0.5)\n"
        "print(sid, flush=True)\n"
    )
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
    }
    done = subprocess.run(
        [sys.executable, "-c", code, url], cwd=ROOT, env=env, capture_output=True, check=False,
        text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    with open_store(url) as st:
        assert st.telemetry.span(int(done.stdout)).samples == 200


def test_rows_of_numeric_strings_are_stored_as_numbers(store: Store) -> None:
    """A row read from a text file (a batch import) holds strings: stored as numbers."""
    sid = running(store)
    rec = store.recorder(sid, background=False)
    rows = telemetry(0.003)
    for row in rows:
        rec.add_row(tuple(repr(float(x)) for x in row))
    rec.close()
    got = store.telemetry.load(sid)
    np.testing.assert_array_equal(got.column("t"), rows[:, 0])
    np.testing.assert_allclose(got.column("w"), rows[:, INDEX["w"]], rtol=1e-6)  # float32
