"""The e-stop gate (issue 12.2): ``POST /api/v1/machine/estop`` reaches the worker even while
the web process cannot run at all, and it is refused exactly as the API refuses it.

The web process is frozen with SIGSTOP (the worst "busy event loop" there is): its worker
keeps driving the session, the gate answers the e-stop, and the worker's ring holds the
zero-torque record; once the web process runs again, the session is stored as stopped by the
e-stop. Against a real ``ergoseek serve``."""

from __future__ import annotations

import contextlib
import os
import signal
import time
from pathlib import Path

import httpx
import pytest

from testing.flood import MB, raw_request, request_head
from testing.server import PASSWORDS, ServerProcess, start_server

pytestmark = pytest.mark.realtime  # timed where it happens: alone, after the parallel rooms


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> ServerProcess:
    with start_server(tmp_path_factory.mktemp("gate")) as srv:
        yield srv


def _session(server: ServerProcess) -> int:
    with server.client("trainer") as c:
        c.post("/api/v1/machine/reset")
        uid = c.post("/api/v1/users", json={"name": "Gate"}).json()["id"]
        r = c.post("/api/v1/sessions", json={"user_id": uid, "duration": 60})
        assert r.status_code == 201, r.text
        return int(r.json()["id"])


def test_an_estop_while_the_web_process_is_frozen(server: ServerProcess) -> None:
    sid = _session(server)
    time.sleep(1.0)
    headers = server.headers("trainer")
    os.kill(server.pid, signal.SIGSTOP)
    try:
        t0 = time.monotonic()
        r = httpx.post(server.url + "/api/v1/machine/estop", headers=headers, timeout=10)
        answered = time.monotonic() - t0
    finally:
        os.kill(server.pid, signal.SIGCONT)
    assert r.status_code == 202 and r.json() == {"status": "estopped"}, r.text
    assert answered < 5.0  # (the frozen web process could never have answered)
    body = server.wait_status(sid, {"stopped", "aborted", "completed", "faulted"}, 20)
    assert body["session"]["status"] == "stopped" and body["session"]["abort_reason"] == "e-stop"
    with server.client("viewer") as c:
        assert c.get("/api/v1/machine").json()["state"] == "estopped"
        kinds = [e["kind"] for e in c.get(f"/api/v1/sessions/{sid}/events").json()]
    assert "estop" in kinds
    with server.client("trainer") as c:
        assert c.post("/api/v1/machine/reset").status_code == 202


def test_the_gate_refuses_what_the_api_refuses(server: ServerProcess) -> None:
    sid = _session(server)
    url = server.url + "/api/v1/machine/estop"
    with server.browser_client("trainer", PASSWORDS["trainer"]) as c:
        cookie = c.cookies["ergoseek_session"]
    refused = [
        (httpx.post(url), 401),
        (httpx.post(url, headers={"Authorization": "Bearer forged"}), 401),
        (httpx.post(url, headers=server.headers("viewer")), 403),
        (httpx.post(url, headers={"Cookie": f"ergoseek_session={cookie}"}), 403),  # no Origin
        (
            httpx.post(
                url,
                headers={
                    "Cookie": f"ergoseek_session={cookie}",
                    "Origin": "http://evil.example",
                },
            ),
            403,
        ),
        (
            httpx.post(url, headers={**server.headers("trainer"), "Host": "evil.example"}),
            400,
        ),
    ]
    for r, code in refused:
        assert r.status_code == code, (code, r.text)
    big = request_head(
        "POST", "/api/v1/machine/estop", f"127.0.0.1:{server.port}",
        {**server.headers("trainer"), "Content-Length": str(50 * MB)},
    )  # fmt: skip
    assert raw_request(server.port, big, timeout=10).status == 413
    with server.client("viewer") as c:
        assert c.get(f"/api/v1/sessions/{sid}").json()["session"]["status"] == "running"
    # and with the cookie from our own page, it stops
    r = httpx.post(url, headers={"Cookie": f"ergoseek_session={cookie}", "Origin": server.url})
    assert r.status_code == 202
    assert server.wait_status(sid, {"stopped"}, 20)["session"]["status"] == "stopped"
    with server.client("trainer") as c:
        assert c.post("/api/v1/machine/reset").status_code == 202


def test_the_gate_forgets_an_ended_login_at_once(server: ServerProcess) -> None:
    url = server.url + "/api/v1/machine/estop"
    with server.client("admin") as c:
        acc = c.post(
            "/api/v1/accounts",
            json={"login": "gatekeeper", "password": "orbit staple ninth", "role": "trainer"},
        ).json()
    login = {"login": "gatekeeper", "password": "orbit staple ninth"}
    tokens = [
        httpx.post(server.url + "/api/v1/auth/token", json=login).json()["access_token"]
        for _ in range(3)
    ]
    h = [{"Authorization": f"Bearer {t}"} for t in tokens]
    assert httpx.post(url, headers=h[0]).status_code in (202, 409)  # known to the gate
    with server.client("trainer") as c:
        c.post("/api/v1/machine/reset")
    httpx.post(server.url + "/api/v1/auth/logout", headers=h[0]).raise_for_status()
    assert httpx.post(url, headers=h[0]).status_code == 401  # logged out: at once
    with server.client("admin") as c:
        c.patch(f"/api/v1/accounts/{acc['id']}", json={"role": "viewer"}).raise_for_status()
    assert httpx.post(url, headers=h[1]).status_code == 403  # demoted: at once
    with server.client("admin") as c:
        c.patch(f"/api/v1/accounts/{acc['id']}", json={"disabled": True}).raise_for_status()
    assert httpx.post(url, headers=h[2]).status_code == 401  # disabled: at once


def _gate_pid(server_pid: int) -> int | None:
    for entry in Path("/proc").iterdir():
        with contextlib.suppress(OSError, ValueError, IndexError):
            stat = (entry / "stat").read_text()
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            if ppid == server_pid and (entry / "comm").read_text().strip() == "ergoseek-gate":
                return int(entry.name)
    return None


def test_without_its_gate_the_server_still_listens(server: ServerProcess) -> None:
    # (last in this module: the gate does not come back)
    gate = _gate_pid(server.pid)
    assert gate is not None
    os.kill(gate, signal.SIGKILL)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        with contextlib.suppress(httpx.HTTPError):
            if httpx.get(server.url + "/healthz", timeout=2).status_code == 200:
                break
        time.sleep(0.1)
    sid = _session(server)
    r = httpx.post(server.url + "/api/v1/machine/estop", headers=server.headers("trainer"))
    assert r.status_code == 202  # now through the API route
    assert server.wait_status(sid, {"stopped"}, 20)["session"]["abort_reason"] == "e-stop"
    assert "the e-stop gate exited" in server.log()
