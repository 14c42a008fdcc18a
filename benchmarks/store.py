"""The store's costs: persisting a session live, listing sessions, loading telemetry.

    python benchmarks/store.py [--json] [--url URL]

Runs against a temporary SQLite file (the default backend), or against ``--url``, an empty
database (e.g. PostgreSQL) that it fills. Prints one JSON object with ``--json``:

- ``write_cpu_share``: share of one core the store needs to persist a 1 kHz session
  (10 channels) plus its evaluations: 60 s of simulated telemetry fed through a
  :class:`~sessions.store.SessionRecorder` in 10 ms blocks, flushed every 0.5 s of session
  time (the cadence its background thread keeps in real time), as fast as it goes; the
  process CPU time (all threads: encoding, SQLite) divided by 60 s. Best of three.
- ``list_10k_ms``: first page (50) of the session list, newest first, with 10 000 sessions
  stored (median of 20); ``list_10k_filtered_ms``: one user's completed sessions, page 3.
- ``load_full_10min_ms``: a 10-minute session's telemetry at full rate (600 000 × 10) into
  one array (median of 5); ``load_decimated_2000_ms``: the same decimated to 2000 points.
- ``bytes_per_session_minute``: stored telemetry (payload + overview) per session minute;
  ``db_bytes_per_session_minute``: growth of the database per minute of a session, all
  included (SQLite only).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

from sessions.config import parse_session_config
from sessions.simulation import run_simulation
from sessions.store import Store, open_store
from sessions.store.database import sqlite_path
from sessions.summary import SessionSummary

TARGETS = {
    "write_cpu_share": 0.05,
    "list_10k_ms": 50.0,
    "load_full_10min_ms": 200.0,
    "load_decimated_2000_ms": 50.0,
}


def _config(seconds: float) -> object:
    return parse_session_config(
        {
            "duration": seconds,
            "rate": 1000.0,
            "user": {"noise": 0.03, "ripple": 0.1, "fatigue_tau": 600.0},
        }
    )


def _record(store: Store, user_id: int, seconds: float) -> tuple[int, float]:
    """A simulated session fed as a live one; its id and the CPU seconds it took."""
    cfg = _config(seconds)
    sim = run_simulation(cfg)  # type: ignore[arg-type]
    rows, evs = sim.telemetry, sim.evaluations
    sid = store.sessions.start(user_id, cfg).id
    cpu = time.process_time()
    rec = store.recorder(sid, background=False, flush_interval=1.0)
    next_flush, k = 0.5, 0
    for i in range(0, len(rows), 10):
        block = rows[i : i + 10]
        rec.add_rows(block)
        t = block[-1, 0]
        while k < len(evs) and evs[k].t <= t:
            rec.add_evaluation(evs[k])
            k += 1
        if t >= next_flush:
            rec.flush()
            next_flush += 0.5
    rec.finish("completed")
    return sid, time.process_time() - cpu


def _median_ms(fn: Callable[[], object], repeat: int) -> float:
    fn()  # warm: the server reads a page it just listed, or a session just opened
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1000 * statistics.median(times)


def _fill_sessions(store: Store, count: int) -> list[int]:
    users = [store.users.create(f"user {i}").id for i in range(20)]
    cfg = _config(120.0)
    t0 = datetime(2025, 1, 1, tzinfo=UTC)
    statuses = ("completed", "completed", "completed", "stopped", "aborted")
    rng = np.random.default_rng(1)
    with store.transaction():
        for i in range(count):
            when = t0 + timedelta(minutes=int(rng.integers(0, 525_600)))
            sid = store.sessions.start(users[i % len(users)], cfg, started_at=when).id
            store.sessions.finish(
                sid,
                statuses[i % len(statuses)],  # type: ignore[arg-type]
                SessionSummary(duration=120.0, mean_power=5.0, peak_power=9.0, work=600.0),
                ended_at=when + timedelta(minutes=2),
            )
    return users


def run(url: str | None) -> dict[str, object]:
    load0 = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="ergoseek-bench-") as tmp:
        db = url or f"sqlite:///{Path(tmp) / 'bench.sqlite3'}"
        path = sqlite_path(db)
        store = open_store(db)
        dialect = store.dialect
        try:
            user = store.users.create("bench").id
            size0 = path.stat().st_size if path else 0
            # 1. live writing: 60 s at 1 kHz, best of three
            cpu = min(_record(store, user, 60.0)[1] for _ in range(3))
            # 2. a 10-minute session: its size, then loading it
            sid, _ = _record(store, user, 600.0)
        finally:
            store.close()  # checkpoints SQLite's WAL into the file
        db_bytes = (path.stat().st_size - size0) / 13.0 if path else None  # 3 × 1 + 10 min
        store = open_store(db)
        try:
            span = store.telemetry.span(sid)
            assert span.samples == 600_000
            full_ms = _median_ms(lambda: store.telemetry.load(sid), 5)
            dec_ms = _median_ms(lambda: store.telemetry.load(sid, points=2000), 10)
            # 3. listing with 10 000 sessions
            users = _fill_sessions(store, 10_000)
            assert store.sessions.list().total >= 10_000
            list_ms = _median_ms(lambda: store.sessions.list(limit=50), 20)
            filtered_ms = _median_ms(
                lambda: store.sessions.list(
                    user_id=users[3], status="completed", limit=50, offset=100
                ),
                20,
            )
        finally:
            store.close()
    out: dict[str, object] = {
        "backend": dialect,
        "write_cpu_share": round(cpu / 60.0, 4),
        "list_10k_ms": round(list_ms, 2),
        "list_10k_filtered_ms": round(filtered_ms, 2),
        "load_full_10min_ms": round(full_ms, 1),
        "load_decimated_2000_ms": round(dec_ms, 2),
        "bytes_per_session_minute": round(span.stored_bytes / 10),
        "db_bytes_per_session_minute": None if db_bytes is None else round(db_bytes),
        "targets": TARGETS,
        "loadavg_1min": [round(load0, 2), round(os.getloadavg()[0], 2)],
        "started": time.strftime("%Y-%m-%dT%H:%M:%S"),
    }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--url", help="an empty database to use instead of a temporary SQLite file")
    args = ap.parse_args()
    out = run(args.url)
    if args.json:
        print(json.dumps(out))
        return
    for key, value in out.items():
        target = TARGETS.get(key)
        print(f"{key:28s} {value}" + (f"   (target ≤ {target})" if target else ""))


if __name__ == "__main__":
    main()
