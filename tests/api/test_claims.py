"""What docs/server.md promises and nothing else tested, through a real server:

- a password change ends every login of the account (tokens, cookies, open live sockets);
- 409 for deleting a user whose session is running, and for deleting one's own account,
  and either refusal changes nothing;
- a stopped session (torque ramped out) stores no setpoint for its user;
- ``{"rate": N}`` sent on the live socket changes the rate of what follows, by the data
  (sequence numbers a multiple of loop rate / N), not by wall time;
- the per-address failed-login limit: four times ``login_attempts`` failures from one address,
  whatever the names, lock that address (429 with Retry-After, even for a right password).
"""

from __future__ import annotations

import itertools
import json
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from testing.server import ServerProcess, start_server

STRONG = "correct horse battery staple 42"
NEWER = "a different long pass phrase 17"


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    with start_server(tmp_path_factory.mktemp("claims")) as srv:
        yield srv


def _token(srv: ServerProcess, login: str, password: str) -> httpx.Response:
    return httpx.post(
        f"{srv.url}/api/v1/auth/token", json={"login": login, "password": password}, timeout=20
    )


def test_a_password_change_ends_every_login_of_the_account(server: ServerProcess) -> None:
    with server.client("admin") as admin:
        acc = admin.post(
            "/api/v1/accounts", json={"login": "moving", "password": STRONG, "role": "trainer"}
        ).json()["id"]
        tokens = [_token(server, "moving", STRONG).json()["access_token"] for _ in range(2)]
        with httpx.Client(base_url=server.url, headers={"Origin": server.url}) as browser:
            login = {"login": "moving", "password": STRONG}
            browser.post("/api/v1/auth/login", json=login).raise_for_status()
            assert browser.get("/api/v1/auth/me").status_code == 200
            bearer = {"Authorization": f"Bearer {tokens[0]}"}
            with connect(f"{server.ws_url}/api/v1/live", additional_headers=bearer) as ws:
                assert json.loads(ws.recv(timeout=10))["type"] == "hello"
                r = admin.patch(f"/api/v1/accounts/{acc}", json={"password": NEWER})
                assert r.status_code == 200, r.text
                # the open socket is closed (1008), not left to the 30 s re-check
                with pytest.raises(ConnectionClosed) as closed:
                    deadline = time.monotonic() + 5.0
                    while time.monotonic() < deadline:
                        ws.recv(timeout=deadline - time.monotonic())
                assert closed.value.rcvd is not None and closed.value.rcvd.code == 1008
            assert browser.get("/api/v1/auth/me").status_code == 401  # the cookie
        for token in tokens:  # both tokens
            r = httpx.get(
                f"{server.url}/api/v1/auth/me", headers={"Authorization": f"Bearer {token}"}
            )
            assert r.status_code == 401
        assert _token(server, "moving", STRONG).status_code == 401  # the old password
        assert _token(server, "moving", NEWER).status_code == 200  # the new one


def test_deleting_ones_own_account_is_409_and_changes_nothing(server: ServerProcess) -> None:
    with server.client("admin") as c:
        me = c.get("/api/v1/auth/me").json()["account"]
        r = c.delete(f"/api/v1/accounts/{me['id']}")
        assert r.status_code == 409 and "own account" in r.text
        assert c.get(f"/api/v1/accounts/{me['id']}").status_code == 200
        assert c.get("/api/v1/auth/me").status_code == 200  # still logged in


def test_a_running_users_delete_is_409_and_a_stopped_session_sets_no_optimum(
    server: ServerProcess,
) -> None:
    with server.client("trainer") as c:
        uid = c.post("/api/v1/users", json={"name": "Busy"}).json()["id"]
        r = c.post(
            "/api/v1/sessions",
            json={"user_id": uid, "duration": 60.0, "seeker": {"kind": "brent"}},
        )
        assert r.status_code == 201, r.text
        sid = r.json()["id"]
        refused = c.delete(f"/api/v1/users/{uid}")
        assert refused.status_code == 409 and "running" in refused.text
        assert c.get(f"/api/v1/users/{uid}").status_code == 200
        assert c.get(f"/api/v1/sessions/{sid}").json()["session"]["status"] == "running"
        assert c.post(f"/api/v1/sessions/{sid}/stop").status_code == 202
        body = server.wait_status(sid, {"stopped", "completed", "aborted", "faulted"}, 20.0)
        assert body["session"]["status"] == "stopped", body["session"]
        sp = c.get(f"/api/v1/users/{uid}/setpoints").json()
        assert sp["current"] is None and sp["history"] == []  # a stopped session sets none
        assert c.delete(f"/api/v1/users/{uid}").status_code == 204  # not running: allowed
        assert c.get(f"/api/v1/users/{uid}").status_code == 404
        assert c.get(f"/api/v1/sessions/{sid}").status_code == 404  # with its sessions


def _telemetry(ws: object, n: int) -> list[dict]:
    out: list[dict] = []
    deadline = time.monotonic() + 15.0
    while len(out) < n:
        left = deadline - time.monotonic()
        assert left > 0, f"only {len(out)} telemetry frames"
        frame = json.loads(ws.recv(timeout=left))  # type: ignore[attr-defined]
        if frame["type"] == "telemetry":
            out.append(frame)
    return out


def test_the_live_rate_changes_on_request(server: ServerProcess) -> None:
    with server.client("trainer") as c:
        uid = c.post("/api/v1/users", json={"name": "Rate"}).json()["id"]
        sid = c.post("/api/v1/sessions", json={"user_id": uid, "duration": 60.0}).json()["id"]
        try:
            url = f"{server.ws_url}/api/v1/live?rate=10"
            with connect(url, additional_headers=server.headers("viewer")) as ws:
                assert json.loads(ws.recv(timeout=10))["rate"] == 10
                slow = _telemetry(ws, 3)
                assert all(f["rate"] == 10 for f in slow)
                assert all(s % 100 == 0 for f in slow for s in f["seq"])  # 10 Hz of 1 kHz
                ws.send(json.dumps({"rate": 250}))
                fast, deadline = [], time.monotonic() + 10.0
                while not fast or fast[-1]["rate"] != 250:  # frames already on their way
                    assert time.monotonic() < deadline, "the rate never changed"
                    fast = _telemetry(ws, 1)
                fast += _telemetry(ws, 5)
                seq = [s for f in fast for s in f["seq"]]
                assert all(s % 4 == 0 for s in seq)  # 250 Hz of 1 kHz
                assert any(s % 100 for s in seq)  # more than the 10 Hz samples
                steps = {b - a for a, b in itertools.pairwise(seq)}
                assert steps == {4}, steps  # every 4th sample, none missing
        finally:
            c.post(f"/api/v1/sessions/{sid}/stop")
            server.wait_status(sid, {"stopped", "completed", "aborted", "faulted"}, 20.0)


def test_one_address_is_limited_whatever_the_names(tmp_path: Path) -> None:
    env = {"ERGOSEEK_LOGIN_ATTEMPTS": "2"}  # → 8 failures per address, whatever the names
    with start_server(tmp_path, env=env) as srv:
        good = srv.passwords()["viewer"]
        for i in range(8):  # one failure per name: no name reaches its own limit of 2
            assert _token(srv, f"nobody{i}", "wrong").status_code == 401
        r = _token(srv, "viewer", good)
        assert r.status_code == 429 and int(r.headers["retry-after"]) >= 1
        assert _token(srv, "admin", srv.passwords()["admin"]).status_code == 429
