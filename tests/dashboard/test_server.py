"""The dashboard's server side without a browser: the real app (simulated machine, a
temporary SQLite store, the viser server) in Starlette's TestClient.

The login page and ``/dashboard/`` (logged-in accounts only, gzipped) under strict
Content-Security-Policies; the WebSocket proxy refuses before accept without a login,
without or with a foreign Origin, without viser's subprotocol, and relays viser's frames;
each browser gets a dashboard of its own (a viewer's without controls) and the shared GUI
holds nothing a browser could change; the viser server is on a private Unix socket and
refuses, at the handshake, anything but the proxy, listening on no TCP port; viser's own
update handler keeps an element's callbacks even for a connection with the secret;
``stop()`` is idempotent and removes the socket; a socket closes when its login ends.
"""

from __future__ import annotations

import base64
import contextlib
import hashlib
import os
import re
import stat
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect
from websockets.exceptions import InvalidStatus

from server.app import create_app
from server.settings import Settings
from sessions.store import open_store
from testing.live import wait_for
from testing.viser_wire import (
    CAMERA,
    SUBPROTOCOL,
    decode,
    encode,
    gui_update,
    open_unix,
    tcp_listeners,
)
from webui.upstream import PROXY_HEADER

ORIGIN = "http://testserver"
ACCOUNTS = {
    "coach": ("trainer", "coach-Pw-7731-kqZ"),
    "guest": ("viewer", "guest-Pw-5512-mvT"),
}


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


def policy(header: str) -> dict[str, list[str]]:
    """A Content-Security-Policy header as directive → sources."""
    out = {}
    for part in header.split(";"):
        name, *sources = part.split()
        out[name] = sources
    return out


def sha256(text: str) -> str:
    return "'sha256-" + base64.b64encode(hashlib.sha256(text.encode()).digest()).decode() + "'"


def test_login_page_and_dashboard_page(app_client: TestClient) -> None:
    r = app_client.get("/")
    assert r.status_code == 200 and 'id="login"' in r.text
    login_csp = policy(r.headers["content-security-policy"])
    (script,) = re.findall(r"<script>(.*?)</script>", r.text, re.S)
    assert login_csp["script-src"] == [sha256(script)]  # its own script, nothing else
    assert login_csp["frame-ancestors"] == ["'none'"] and login_csp["default-src"] == ["'none'"]
    r = app_client.get("/dashboard/", follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == "/"
    cookie = logged_in(app_client, "coach")
    r = app_client.get("/", headers=cookie)
    assert 'Signed in as <strong id="who">coach (trainer)</strong>' in r.text
    r = app_client.get("/dashboard/", headers={**cookie, "Accept-Encoding": "gzip"})
    assert r.status_code == 200 and r.headers["content-encoding"] == "gzip"
    assert "<title>Viser</title>" in r.text  # (decoded by the client)
    csp = policy(r.headers["content-security-policy"])
    # viser's loader (its one inline script) and the app module it inserts; no inline
    # script, handler or eval of anything else.
    (loader,) = re.findall(r"<script [^>]*>(.*?)</script>", r.text, re.S)
    hashes = [s for s in csp["script-src"] if s.startswith("'sha256-")]
    assert sha256(loader) in hashes and len(hashes) == 2
    assert set(csp["script-src"]) == {*hashes, "'wasm-unsafe-eval'"}
    assert csp["default-src"] == ["'none'"] and csp["object-src"] == ["'none'"]
    assert csp["connect-src"] == ["'self'", "data:"]  # (no ?websocket= to another server)
    assert csp["frame-ancestors"] == ["'none'"] and csp["frame-src"] == ["'none'"]
    assert r.headers["x-frame-options"] == "DENY"
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


def proxied(client: TestClient, login: str) -> Any:
    """A dashboard socket through the proxy, logged in as ``login``."""
    headers = {**logged_in(client, login), "origin": ORIGIN}
    return client.websocket_connect("/dashboard", headers=headers, subprotocols=[SUBPROTOCOL])


def elements(ws: Any, timeout: float = 20.0) -> dict[str, dict[str, Any]]:
    """label → creation message of the GUI elements of a browser's own dashboard, received
    until its last-built part (the seeker's progress bar) has arrived (after the first
    camera message, which the caller sent)."""
    seen: dict[str, dict[str, Any]] = {}
    deadline = time.monotonic() + timeout
    while "(progress)" not in seen:
        assert time.monotonic() < deadline, f"the dashboard never completed: {sorted(seen)}"
        for m in decode(ws.receive_bytes()):
            if m.get("type") == "GuiProgressBarMessage":
                seen["(progress)"] = m
            elif m.get("type", "").startswith("Gui") and isinstance(m.get("props"), dict):
                seen.setdefault(str(m["props"].get("label")), m)
    return seen


def test_trainers_and_viewers_get_their_own_dashboards(app_client: TestClient) -> None:
    runtime = app_client.app.state.runtime  # type: ignore[attr-defined]
    ctx = runtime.dashboard.ctx
    for login, controls in (("coach", True), ("guest", False)):
        with proxied(app_client, login) as ws:
            assert ws.accepted_subprotocol == SUBPROTOCOL
            assert len(ws.receive_bytes()) > 1000  # viser's shared state, relayed untouched
            ws.send_bytes(encode(CAMERA))
            got = elements(ws)
            assert "History of" in got
            assert ("E-STOP" in got) is controls and ("Start" in got) is controls
            assert ("Profile" in got) is controls  # the Users tab
            deadline = time.monotonic() + 5
            views = []
            while not views and time.monotonic() < deadline:  # (registered once built)
                views = [v for v in ctx.views() if v.who.login == login]
                time.sleep(0.05)
            assert len(views) == 1
            assert views[0].who.role == ACCOUNTS[login][0]


def test_a_dashboard_opened_after_a_user_was_added_elsewhere_lists_them(
    app_client: TestClient,
) -> None:
    """A user added where this web process is not told (another process on the store) while
    no dashboard is open: the next dashboard's pickers list them from their first frame (the
    picker was built from the users read at start-up, and a re-read during the build missed
    the new view: the user never appeared)."""
    runtime = app_client.app.state.runtime  # type: ignore[attr-defined]
    # (the watch re-reads nothing while none is open; the last test's dashboard is closed
    # by the viser server's own thread, a moment after its socket)
    assert wait_for(lambda: not runtime.dashboard.ctx.views(), 10.0)
    user = runtime.store.users.create("Added elsewhere")
    with proxied(app_client, "coach") as ws:
        ws.receive_bytes()
        ws.send_bytes(encode(CAMERA))
        got = elements(ws)
    for picker in ("User", "History of"):
        assert f"Added elsewhere (#{user.id})" in got[picker]["props"]["options"], picker


def test_one_account_opens_a_bounded_number_of_dashboards(app_client: TestClient) -> None:
    from webui.proxy import MAX_PER_ACCOUNT

    with contextlib.ExitStack() as open_ones:
        for _ in range(MAX_PER_ACCOUNT):
            ws = open_ones.enter_context(proxied(app_client, "coach"))
            ws.receive_bytes()
        headers = {**logged_in(app_client, "coach"), "origin": ORIGIN}
        assert refused(app_client, headers, [SUBPROTOCOL])
        headers = {**logged_in(app_client, "guest"), "origin": ORIGIN}
        assert not refused(app_client, headers, [SUBPROTOCOL])  # another account: fine


def test_the_shared_gui_holds_nothing_a_browser_could_change(app_client: TestClient) -> None:
    server = app_client.app.state.runtime.dashboard.server  # type: ignore[attr-defined]
    assert server.gui._gui_input_handle_from_uuid == {}


def raw_unix(path: str, headers: dict[str, str] | None) -> int | list[dict[str, Any]]:
    """The HTTP status a handshake on the socket was refused with, or what it received."""
    try:
        with open_unix(path, headers) as raw:
            raw.hello()
            return raw.receive(1.5)
    except InvalidStatus as exc:
        return int(exc.response.status_code)


def http_unix(path: str, headers: dict[str, str]) -> int:
    """A plain HTTP GET / on the socket: its status."""
    import http.client
    import socket

    class Conn(http.client.HTTPConnection):
        def connect(self) -> None:
            self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            self.sock.connect(path)

    conn = Conn("localhost", timeout=5)
    conn.request("GET", "/", headers=headers)
    status = conn.getresponse().status
    conn.close()
    return status


def test_the_upstream_accepts_only_the_proxy(app_client: TestClient) -> None:
    dashboard = app_client.app.state.runtime.dashboard  # type: ignore[attr-defined]
    path = dashboard.socket_path
    assert stat.S_ISSOCK(os.stat(path).st_mode)
    assert stat.S_IMODE(os.stat(Path(path).parent).st_mode) == 0o700  # this user only
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
    assert raw_unix(path, None) == 403  # refused at the handshake: no frame, no GUI state
    assert raw_unix(path, {PROXY_HEADER: "guessed"}) == 403
    assert http_unix(path, {}) == 403
    assert http_unix(path, {PROXY_HEADER: dashboard.bridge.secret}) == 404  # no file server
    # The secret without an account the proxy vouches for: closed, no dashboard of its own.
    got = raw_unix(path, {PROXY_HEADER: dashboard.bridge.secret})
    assert isinstance(got, list)
    assert not [m for m in got if m.get("props", {}).get("label") == "E-STOP"]


def test_the_dashboard_listens_on_no_tcp_port(tmp_path: Path) -> None:
    before = tcp_listeners(os.getpid())
    app = create_app(Settings(database_url=f"sqlite:///{tmp_path / 'db.sqlite3'}", machine="sim"))
    with TestClient(app):  # (no uvicorn: whatever listens now is the dashboard's)
        assert app.state.runtime.dashboard is not None
        assert tcp_listeners(os.getpid()) - before == set()


def test_viser_itself_refuses_to_rewire_an_element(app_client: TestClient) -> None:
    """Behind the proxy's filter: viser's own handler, for a connection that has the secret
    (as if the proxy let anything through)."""
    runtime = app_client.app.state.runtime  # type: ignore[attr-defined]
    dashboard, store = runtime.dashboard, runtime.store
    coach = store.accounts.by_login("coach")
    headers = dashboard.bridge.upstream_headers(coach)
    sessions = store.sessions.list(limit=1).total
    with open_unix(dashboard.socket_path, headers) as raw:
        raw.hello()
        estop, start = raw.wait_for("E-STOP"), raw.wait_for("Start")
        for attack in ({"update_cb": []}, {"removed": True}, {"is_button": False}):
            raw.send(gui_update(estop, **attack))
        raw.send(gui_update(raw.wait_for("Duration (s)"), value=1e9))  # beyond its bounds
        raw.send(gui_update(raw.wait_for("Controller"), value="not-a-controller"))
        raw.receive(0.5)
        view = next(v for v in dashboard.ctx.views() if v.who.login == "coach")
        assert view.live.duration.value == 120.0
        assert view.live.controller.value == "rise"
        raw.send(gui_update(estop, value=True))  # still an E-STOP
        deadline = time.monotonic() + 10
        while runtime.machine.status().state != "estopped" and time.monotonic() < deadline:
            raw.receive(0.1)
        assert runtime.machine.status().state == "estopped"
        while {"disabled": True} not in raw.updates_of(start) and time.monotonic() < deadline:
            raw.receive(0.1)  # (latched: the feed disables Start)
        raw.send(gui_update(start, value=True))  # a disabled button is not clicked
        raw.receive(1.0)
        assert store.sessions.list(limit=1).total == sessions
    app_client.post(
        "/api/v1/machine/reset", headers=logged_in(app_client, "coach") | {"origin": ORIGIN}
    )
    deadline = time.monotonic() + 10
    while runtime.machine.status().state != "idle" and time.monotonic() < deadline:
        time.sleep(0.1)


def test_stop_is_idempotent(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'db.sqlite3'}"
    app = create_app(Settings(database_url=url, machine="sim", allowed_hosts=["testserver"]))
    with TestClient(app):
        dashboard = app.state.runtime.dashboard
        assert dashboard is not None
    dashboard.stop()  # the lifespan already stopped it
    dashboard.stop()
    assert dashboard.feed.task is not None and dashboard.feed.task.done()
    assert not Path(dashboard.socket_path).parent.exists()  # the socket's directory is gone


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
