"""``/api/v1/live`` under pressure (issue 12.6): connections capped per account and in all,
refused cleanly (429 at the handshake); a login that ends (account disabled, password
changed, deleted, logged out) closes its open connections at once, not at the next expiry."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator

import httpx
import pytest
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import ClientConnection, connect

from testing.server import ServerProcess, start_server

PER_ACCOUNT, TOTAL = 2, 3


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    env = {
        "ERGOSEEK_LIVE_MAX_PER_ACCOUNT": str(PER_ACCOUNT),
        "ERGOSEEK_LIVE_MAX_TOTAL": str(TOTAL),
    }
    with start_server(tmp_path_factory.mktemp("live"), env=env) as srv:
        yield srv


def _open(server: ServerProcess, headers: dict[str, str]) -> ClientConnection:
    ws = connect(f"{server.ws_url}/api/v1/live", additional_headers=headers)
    assert '"hello"' in str(ws.recv(timeout=10))
    return ws


def _refused(server: ServerProcess, headers: dict[str, str]) -> str:
    with pytest.raises(InvalidStatus) as info:
        connect(f"{server.ws_url}/api/v1/live", additional_headers=headers).close()
    assert info.value.response.status_code == 429
    return info.value.response.body.decode()


def _closed_within(ws: ClientConnection, seconds: float) -> float:
    """Seconds until the server closed ``ws`` (frames in between are read and dropped)."""
    t0 = time.monotonic()
    with contextlib.suppress(ConnectionClosed):
        while time.monotonic() - t0 < seconds:
            with contextlib.suppress(TimeoutError):
                ws.recv(timeout=0.2)
        pytest.fail(f"still open after {seconds} s")
    assert ws.close_code == 1008
    return time.monotonic() - t0


def test_connections_are_capped_per_account_and_in_all(server: ServerProcess) -> None:
    viewer, trainer = server.headers("viewer"), server.headers("trainer")
    with contextlib.ExitStack() as stack:
        for _ in range(PER_ACCOUNT):
            stack.enter_context(_open(server, viewer))
        assert "this account" in _refused(server, viewer)
        stack.enter_context(_open(server, trainer))  # another account: room in all still
        assert "in all" in _refused(server, server.headers("admin"))
    time.sleep(0.5)  # closed ones are counted out
    with _open(server, viewer), _open(server, viewer):
        pass


def _account(server: ServerProcess, login: str) -> tuple[int, dict[str, str]]:
    with server.client("admin") as c:
        acc = c.post(
            "/api/v1/accounts",
            json={"login": login, "password": "orbit staple ninth", "role": "viewer"},
        ).json()
    r = httpx.post(
        server.url + "/api/v1/auth/token", json={"login": login, "password": "orbit staple ninth"}
    )
    return int(acc["id"]), {"Authorization": f"Bearer {r.json()['access_token']}"}


@pytest.mark.parametrize(
    "change",
    [{"disabled": True}, {"password": "ninth orbit staple"}, "delete", "logout"],
    ids=["disabled", "password", "deleted", "logout"],
)
def test_an_ended_login_closes_its_live_connections_at_once(
    server: ServerProcess, change: object
) -> None:
    login = f"watcher{abs(hash(str(change))) % 10_000}"
    acc_id, headers = _account(server, login)
    with _open(server, headers) as ws:
        if change == "logout":
            httpx.post(server.url + "/api/v1/auth/logout", headers=headers).raise_for_status()
        elif change == "delete":
            server.client("admin").delete(f"/api/v1/accounts/{acc_id}").raise_for_status()
        else:
            server.client("admin").patch(f"/api/v1/accounts/{acc_id}", json=change)
        assert _closed_within(ws, 5.0) < 5.0  # (the periodic check would take 30 s)


def test_a_role_change_that_keeps_the_login_keeps_the_connection(server: ServerProcess) -> None:
    acc_id, headers = _account(server, "promoted")
    with _open(server, headers) as ws:
        server.client("admin").patch(f"/api/v1/accounts/{acc_id}", json={"role": "trainer"})
        time.sleep(1.0)
        assert ws.ping().wait(5)  # still open: a trainer may watch too
