"""Crashes: the server killed mid-session, the worker killed under a running server."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import httpx
import numpy as np

from testing.live import wait_for
from testing.processes import exited
from testing.server import start_server, worker_pid


def test_server_killed_mid_session_then_restarted(tmp_path: Path) -> None:
    srv = start_server(tmp_path)
    try:
        with srv.client("trainer") as c:
            uid = c.post("/api/v1/users", json={"name": "Kay"}).json()["id"]
            sid = c.post("/api/v1/sessions", json={"user_id": uid, "duration": 120}).json()["id"]
        time.sleep(4.0)
        wpid = worker_pid(srv.proc.pid)
        assert wpid is not None
        srv.kill()  # kill -9: no shutdown, no goodbye
        deadline = time.monotonic() + 5
        while not exited(wpid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert exited(wpid), "the worker must exit (zero torque) when its parent dies"
    finally:
        srv.kill()
    again = start_server(tmp_path, port=srv.port)
    try:
        with again.client("viewer") as c:
            s = c.get(f"/api/v1/sessions/{sid}").json()["session"]
            assert s["status"] == "aborted" and s["abort_reason"] == "server restarted"
            samples = c.get(f"/api/v1/sessions/{sid}/telemetry", params={"points": 100}).json()
            # ≥ 4 s ran; at most about 1 s may be lost to the crash
            assert samples["samples"] >= 2500
            assert s["duration"] >= 2.5
        with again.client("trainer") as c:  # and the machine works again
            new = c.post("/api/v1/sessions", json={"user_id": uid, "duration": 2})
            assert new.status_code == 201
            assert again.wait_status(new.json()["id"], {"completed"}, 15)["session"]["status"] == (
                "completed"
            )
    finally:
        again.stop()


def test_worker_killed_session_aborted_api_stays_up(tmp_path: Path) -> None:
    with start_server(tmp_path) as srv, srv.client("trainer") as c:
        uid = c.post("/api/v1/users", json={"name": "Lee"}).json()["id"]
        sid = c.post("/api/v1/sessions", json={"user_id": uid, "duration": 120}).json()["id"]
        url = f"/api/v1/sessions/{sid}/telemetry"

        def stored() -> int:
            return int(c.get(url, params={"points": 10}).json()["samples"])

        # wait (event-driven) until at least a second of it is committed to the store
        assert wait_for(lambda: stored() >= 1000, timeout=20.0, every=0.1)
        committed = stored()
        wpid = worker_pid(srv.proc.pid)
        assert wpid is not None
        os.kill(wpid, signal.SIGKILL)
        body = srv.wait_status(sid, {"aborted", "completed", "stopped", "faulted"}, 10)
        assert body["session"]["status"] == "aborted"
        assert "worker" in body["session"]["abort_reason"]
        # the data it had is kept, every period of it: what was committed before the kill
        # and at most what the worker ran, the session clock continuous at the loop's period
        tel = c.get(url, params={"points": 200_000}).json()
        assert not tel["decimated"]
        t = np.asarray(tel["channels"]["t"], dtype=float)
        assert committed <= tel["samples"] == len(t) <= 120_000
        assert np.allclose(np.diff(t), 1e-3) and t[0] < 2e-3
        w = np.asarray(tel["channels"]["w"], dtype=float)
        assert np.all(np.isfinite(w)) and np.ptp(w) > 0.1  # the handle moved: real samples
        csv_rows = c.get(f"{url}.csv").text.strip().splitlines()
        assert len(csv_rows) - sum(r.startswith("#") for r in csv_rows) - 1 == tel["samples"]
        health = httpx.get(srv.url + "/healthz").json()
        assert health["status"] == "degraded" and health["worker"] == "lost"
        assert c.get("/api/v1/machine").json()["state"] == "lost"
        assert c.post("/api/v1/sessions", json={"user_id": uid}).status_code == 409
        assert c.get(f"/api/v1/sessions/{sid}/telemetry").status_code == 200  # data kept
        assert c.post("/api/v1/machine/reset").status_code == 202  # a new worker
        assert c.get("/api/v1/machine").json()["state"] == "idle"
        new = c.post("/api/v1/sessions", json={"user_id": uid, "duration": 2})
        assert new.status_code == 201
        assert (
            srv.wait_status(new.json()["id"], {"completed"}, 15)["session"]["status"] == "completed"
        )


def test_sigterm_ends_the_session_as_stopped(tmp_path: Path) -> None:
    srv = start_server(tmp_path)
    with srv.client("trainer") as c:
        uid = c.post("/api/v1/users", json={"name": "Mo"}).json()["id"]
        sid = c.post("/api/v1/sessions", json={"user_id": uid, "duration": 120}).json()["id"]
    time.sleep(3.0)
    wpid = worker_pid(srv.proc.pid)
    assert srv.stop() in (0, -signal.SIGTERM)  # uvicorn re-raises the signal once shut down
    assert "Application shutdown complete" in srv.log()
    assert wpid is not None and exited(wpid)
    again = start_server(tmp_path, port=srv.port)
    try:
        with again.client("viewer") as c:
            s = c.get(f"/api/v1/sessions/{sid}").json()["session"]
            assert s["status"] == "stopped"
            tel = c.get(f"/api/v1/sessions/{sid}/telemetry", params={"points": 200_000}).json()
            t = np.array(tel["channels"]["t"])
            # nothing lost: every period from the start to the last one before the stop, in order
            # (how many that is depends on how fast the VM ran the 3 s: its stalls skip periods)
            assert not tel["decimated"] and tel["samples"] == len(t)
            assert t[0] == 0.0 and t[-1] >= 2.0
            assert np.allclose(np.diff(t), 1e-3)
    finally:
        again.stop()
