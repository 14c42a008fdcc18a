"""The dashboard's server side without a browser: the real app (simulated machine, a
temporary SQLite store, both viser servers) in Starlette's TestClient.

The login page; ``/dashboard/`` only for a logged-in account, gzipped; the WebSocket proxy
refuses before accept without a login, without or with a foreign Origin, without viser's
subprotocol, and relays viser's frames to trainers and viewers, each to their own server;
GUI actions need a connection that came through the proxy; ``stop()`` is idempotent.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
import viser
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from server.app import create_app
from server.settings import Settings
from sessions.store import open_store

SUBPROTOCOL = f"viser-v{viser.__version__}"
ORIGIN = "http://testserver"
ACCOUNTS = {"coach": ("trainer", "coach-password"), "guest": ("viewer", "guest-password")}


@pytest.fixture(scope="module")
def app_client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    url = f"sqlite:///{Path(tmp_path_factory.mktemp('dash')) / 'db.sqlite3'}"
    with open_store(url) as store:
        for login, (role, password) in ACCOUNTS.items():
            store.accounts.create(login, password, role)
    app = create_app(Settings(database_url=url, machine="sim", allowed_hosts=["testserver"]))
    with TestClient(app) as client:
        yield client


def logged_in(client: TestClient, login: str) -> dict[str, str]:
    """Log in; returns the cookie header a browser would send."""
    _, password = ACCOUNTS[login]
    r = client.post(
        "/api/v1/auth/login",
        json={"login": login, "password": password},
        headers={"Origin": ORIGIN},
    )
    assert r.status_code == 200
    client.cookies.clear()  # send it explicitly, per connection
    return {"cookie": f"ergoseek_session={r.cookies['ergoseek_session']}"}


def refused(client: TestClient, headers: dict[str, str], subprotocols: list[str] | None) -> bool:
    try:
        with client.websocket_connect(  # (it adds to the headers it is given: a copy)
            "/dashboard", headers=dict(headers), subprotocols=subprotocols or []
        ) as ws:
            ws.receive_bytes()
    except WebSocketDisconnect as exc:
        assert exc.code == 1008
        return True
    return False


def test_login_page_and_dashboard_page(app_client: TestClient) -> None:
    r = app_client.get("/")
    assert r.status_code == 200 and 'id="login"' in r.text
    assert "frame-ancestors 'none'" in r.headers["content-security-policy"]
    r = app_client.get("/dashboard/", follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == "/"
    cookie = logged_in(app_client, "coach")
    r = app_client.get("/", headers=cookie)
    assert 'Signed in as <strong id="who">coach (trainer)</strong>' in r.text
    r = app_client.get("/dashboard/", headers={**cookie, "Accept-Encoding": "gzip"})
    assert r.status_code == 200 and r.headers["content-encoding"] == "gzip"
    assert "<title>Viser</title>" in r.text  # (decoded by the client)
    assert "connect-src 'self'" in r.headers["content-security-policy"]
    raw = app_client.get("/dashboard/", headers={**cookie, "Accept-Encoding": "identity"}).content
    assert raw.startswith(b"<!doctype html>")  # identity: not compressed
    assert app_client.get("/dashboard/../../etc/passwd", headers=cookie).status_code == 404
    assert app_client.get("/dashboard/nothing.js", headers=cookie).status_code == 404


def test_the_socket_refuses_before_accepting(app_client: TestClient) -> None:
    cookie = logged_in(app_client, "coach")
    own = {**cookie, "origin": ORIGIN}
    assert refused(app_client, {"origin": ORIGIN}, [SUBPROTOCOL])  # no login
    assert refused(app_client, cookie, [SUBPROTOCOL])  # a cookie needs an Origin
    assert refused(app_client, {**cookie, "origin": "http://evil.example"}, [SUBPROTOCOL])
    assert refused(app_client, own, ["something-else"])  # not viser's client
    assert refused(app_client, {**own, "cookie": "ergoseek_session=forged"}, [SUBPROTOCOL])
    assert not refused(app_client, own, [SUBPROTOCOL])
    app_client.post("/api/v1/auth/logout", headers=own)
    assert refused(app_client, own, [SUBPROTOCOL])  # logged out


def test_trainers_and_viewers_reach_their_own_viser(app_client: TestClient) -> None:
    runtime = app_client.app.state.runtime  # type: ignore[attr-defined]
    dashboard = runtime.dashboard
    control, view = dashboard.servers["control"], dashboard.servers["view"]
    assert dashboard.upstream("trainer").endswith(f":{control.get_port()}")
    assert dashboard.upstream("admin").endswith(f":{control.get_port()}")
    assert dashboard.upstream("viewer").endswith(f":{view.get_port()}")
    for login, server in (("coach", control), ("guest", view)):
        headers = {**logged_in(app_client, login), "origin": ORIGIN}
        with app_client.websocket_connect(
            "/dashboard", headers=headers, subprotocols=[SUBPROTOCOL]
        ) as ws:
            assert ws.accepted_subprotocol == SUBPROTOCOL
            frame = ws.receive_bytes()  # viser's initial state, relayed untouched
            assert len(frame) > 1000
            client_id = max(server._websock_server._live_connections)  # the newest
            account = dashboard.bridge.proxied_account_id(server, client_id)
            assert account == runtime.store.accounts.by_login(login).id
            if login == "coach":
                assert dashboard.bridge.trainer(server, client_id) is not None
            else:
                assert dashboard.bridge.trainer(server, client_id) is None


def test_a_direct_connection_to_viser_cannot_act(app_client: TestClient) -> None:
    from websockets.sync.client import connect

    dashboard = app_client.app.state.runtime.dashboard  # type: ignore[attr-defined]
    control = dashboard.servers["control"]
    with connect(
        dashboard.upstream("trainer"),
        subprotocols=[SUBPROTOCOL],
        max_size=2**26,  # type: ignore[list-item]
    ) as ws:
        ws.recv(timeout=10)
        client_id = max(control._websock_server._live_connections)
        assert dashboard.bridge.proxied_account_id(control, client_id) is None
        assert dashboard.bridge.trainer(control, client_id) is None
    assert control.request_share_url() is None  # the share tunnel is disabled


def test_stop_is_idempotent(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'db.sqlite3'}"
    app = create_app(Settings(database_url=url, machine="sim", allowed_hosts=["testserver"]))
    with TestClient(app):
        dashboard = app.state.runtime.dashboard
        assert dashboard is not None
    dashboard.stop()  # the lifespan already stopped it
    dashboard.stop()
    assert dashboard.feed.task is not None and dashboard.feed.task.done()


@pytest.mark.timeout(60)
def test_an_open_socket_closes_when_its_login_ends(
    app_client: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    import webui.proxy

    monkeypatch.setattr(webui.proxy, "RECHECK_S", 0.3)
    headers = {**logged_in(app_client, "coach"), "origin": ORIGIN}
    with app_client.websocket_connect(
        "/dashboard", headers=dict(headers), subprotocols=[SUBPROTOCOL]
    ) as ws:
        ws.receive_bytes()
        app_client.post("/api/v1/auth/logout", headers=headers)
        with pytest.raises(WebSocketDisconnect) as closed:
            while True:  # viser's updates until the proxy notices the logout
                ws.receive_bytes()
        assert closed.value.code == 1008
