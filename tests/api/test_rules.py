"""Smaller rules of issue 12.6 against a real server: a reset never pretends (409 during a
session), a replaced worker leaves no traceback, seeds and manual setpoints within what the
engine and the machine take, query errors that name the query, logins purged when expired."""

from __future__ import annotations

import os
import signal
import threading
import time
from datetime import UTC, datetime, timedelta

import pytest
from sqlalchemy import create_engine, text

from sessions.requests import HEADROOM
from sessions.store import open_store
from testing.server import ServerProcess, start_server, worker_pid


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> ServerProcess:
    with start_server(tmp_path_factory.mktemp("rules")) as srv:
        yield srv


@pytest.fixture(scope="module")
def uid(server: ServerProcess) -> int:
    with server.client("trainer") as c:
        return int(c.post("/api/v1/users", json={"name": "Rule"}).json()["id"])


def _loc(r, *loc: object) -> str:  # type: ignore[no-untyped-def]
    assert r.status_code == 422, r.text
    (item,) = r.json()["detail"]
    assert item["loc"] == list(loc), item
    return str(item["msg"])


def test_reset_during_a_session_is_409_and_changes_nothing(server: ServerProcess, uid: int) -> None:
    with server.client("trainer") as c:
        sid = c.post("/api/v1/sessions", json={"user_id": uid, "duration": 30}).json()["id"]
        r = c.post("/api/v1/machine/reset")
        assert r.status_code == 409 and "running" in r.json()["detail"], r.text
        assert c.get(f"/api/v1/sessions/{sid}").json()["session"]["status"] == "running"
        assert c.post(f"/api/v1/sessions/{sid}/stop").status_code == 202
        server.wait_status(sid, {"stopped"}, 15)


@pytest.mark.parametrize("seed", [2**63, 2**64, 10**400, -1])
def test_a_seed_beyond_the_engines_rng_is_refused(
    server: ServerProcess, uid: int, seed: int
) -> None:
    with server.client("trainer") as c:
        before = c.get("/api/v1/sessions").json()["total"]
        body = f'{{"user_id": {uid}, "duration": 5, "seed": {seed}}}'
        r = c.post("/api/v1/sessions", content=body, headers={"Content-Type": "application/json"})
        _loc(r, "body", "seed")
        assert c.get("/api/v1/sessions").json()["total"] == before
        ok = c.post("/api/v1/sessions", json={"user_id": uid, "duration": 1, "seed": 2**63 - 1})
        assert ok.status_code == 201, ok.text
        server.wait_status(ok.json()["id"], {"completed"}, 15)


def test_a_manual_setpoint_stays_within_the_machine(server: ServerProcess, uid: int) -> None:
    with server.client("viewer") as c:
        vmax = c.get("/api/v1/machine").json()["limits"]["max_velocity"]
    with server.client("trainer") as c:
        for too_fast in (99.0, vmax, HEADROOM * vmax * 1.01):
            r = c.post(f"/api/v1/users/{uid}/setpoints", json={"velocity": too_fast})
            assert "velocity" in _loc(r, "body", "velocity")
        assert c.get(f"/api/v1/users/{uid}/setpoints").json()["history"] == []
        ok = c.post(f"/api/v1/users/{uid}/setpoints", json={"velocity": 0.5 * vmax})
        assert ok.status_code == 201


def test_query_errors_name_the_query(server: ServerProcess, uid: int) -> None:
    with server.client("trainer") as c:
        sid = c.post("/api/v1/sessions", json={"user_id": uid, "duration": 1}).json()["id"]
        server.wait_status(sid, {"completed"}, 15)
        r = c.get(f"/api/v1/sessions/{sid}/telemetry", params={"start": 5, "end": 1})
        assert "before" in _loc(r, "query", "end")
        r = c.get(f"/api/v1/sessions/{sid}/telemetry.csv", params={"start": 5, "end": 1})
        _loc(r, "query", "end")
        _loc(c.get("/api/v1/sessions", params={"limit": 0}), "query", "limit")


def test_expired_logins_are_purged(server: ServerProcess) -> None:
    with open_store(server.database_url) as store:
        acc = store.accounts.by_login("viewer")
        assert acc is not None
        for _ in range(5):
            store.tokens.issue(acc.id, "bearer", timedelta(microseconds=1))
    engine = create_engine(server.database_url)

    def expired() -> int:  # (ids are reused once rows are gone: count by expiry)
        with engine.connect() as conn:
            rows = conn.execute(text("SELECT expires_at FROM auth_tokens")).scalars().all()
        now = datetime.now(UTC).replace(tzinfo=None)
        return sum(datetime.fromisoformat(str(x)).replace(tzinfo=None) <= now for x in rows)

    assert expired() >= 5
    server.tokens.pop("viewer", None)
    server.token("viewer")  # a login
    assert expired() == 0
    engine.dispose()


def test_a_replaced_worker_leaves_no_traceback(server: ServerProcess, uid: int) -> None:
    mark = len(server.log())
    with server.client("trainer") as c:
        sid = c.post("/api/v1/sessions", json={"user_id": uid, "duration": 60}).json()["id"]
        time.sleep(1.0)
        wpid = worker_pid(server.pid)
        assert wpid is not None
        os.kill(wpid, signal.SIGKILL)
        server.wait_status(sid, {"aborted"}, 10)
        done = threading.Event()

        def watch() -> None:  # a status poller, as the dashboard is, all through the resets
            with server.client("viewer") as v:
                while not done.is_set():
                    v.get("/api/v1/machine")

        watchers = [threading.Thread(target=watch) for _ in range(3)]
        for w in watchers:
            w.start()
        try:
            for _ in range(3):  # reset replaces the worker while the pump follows it
                assert c.post("/api/v1/machine/reset").status_code == 202
                time.sleep(0.3)
        finally:
            done.set()
            for w in watchers:
                w.join()
        assert c.get("/api/v1/machine").json()["state"] == "idle"
        again = c.post("/api/v1/sessions", json={"user_id": uid, "duration": 1})
        assert again.status_code == 201
        server.wait_status(again.json()["id"], {"completed"}, 15)
    log = server.log()[mark - 6000 if mark > 6000 else 0 :]
    assert "Traceback" not in log and "has no attribute" not in log, log
