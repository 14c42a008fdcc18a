"""Who may do what: the auth matrix, logins, rate limits, cookies and Origins."""

from __future__ import annotations

import httpx
import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from testing.server import PASSWORDS, ServerProcess, start_server

# (method, path, body, least role); {user} and {acc} are filled in
ROUTES: list[tuple[str, str, dict | None, str]] = [
    ("GET", "/api/v1/auth/me", None, "viewer"),
    ("GET", "/api/v1/users", None, "viewer"),
    ("GET", "/api/v1/users/{user}", None, "viewer"),
    ("GET", "/api/v1/users/{user}/setpoints", None, "viewer"),
    ("GET", "/api/v1/sessions", None, "viewer"),
    ("GET", "/api/v1/machine", None, "viewer"),
    ("POST", "/api/v1/users", {"name": "Zed"}, "trainer"),
    ("PATCH", "/api/v1/users/{user}", {"notes": "ok"}, "trainer"),
    ("POST", "/api/v1/users/{user}/setpoints", {"velocity": 3.0}, "trainer"),
    ("POST", "/api/v1/sessions", {"user_id": 999999}, "trainer"),  # 404 once allowed
    ("POST", "/api/v1/sessions/999999/stop", None, "trainer"),
    ("POST", "/api/v1/machine/reset", None, "trainer"),
    ("GET", "/api/v1/accounts", None, "admin"),
    ("GET", "/api/v1/accounts/{acc}", None, "admin"),
    ("POST", "/api/v1/accounts", {"login": "newbie", "password": "newbie pass phrase"}, "admin"),
    ("PATCH", "/api/v1/accounts/{acc}", {"role": "viewer"}, "admin"),
]
RANK = {"viewer": 0, "trainer": 1, "admin": 2}


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> ServerProcess:
    with start_server(tmp_path_factory.mktemp("auth"), env={"ERGOSEEK_LOGIN_ATTEMPTS": "3"}) as srv:
        yield srv


@pytest.fixture(scope="module")
def ids(server: ServerProcess) -> dict[str, int]:
    with server.client("admin") as c:
        user = c.post("/api/v1/users", json={"name": "Matrix"}).json()["id"]
        acc = c.post(
            "/api/v1/accounts",
            json={"login": "spare", "password": "spare tyre in the boot", "role": "viewer"},
        ).json()["id"]
    return {"user": user, "acc": acc}


@pytest.mark.parametrize(("method", "path", "body", "least"), ROUTES)
def test_auth_matrix(
    server: ServerProcess,
    ids: dict[str, int],
    method: str,
    path: str,
    body: dict | None,
    least: str,
) -> None:
    url = path.format(**ids)
    anon = httpx.request(method, server.url + url, json=body, timeout=10)
    assert anon.status_code == 401, (method, url)
    for role in ("viewer", "trainer", "admin"):
        with server.client(role) as c:
            r = c.request(method, url, json=body)
        if RANK[role] < RANK[least]:
            assert r.status_code == 403, (role, method, url, r.text)
        else:
            assert r.status_code not in (401, 403), (role, method, url, r.text)
            assert r.status_code < 500


def test_health_and_docs_need_no_login(server: ServerProcess) -> None:
    assert httpx.get(server.url + "/healthz").json()["status"] == "ok"
    spec = httpx.get(server.url + "/openapi.json").json()
    start = spec["paths"]["/api/v1/sessions"]["post"]
    assert "examples" in str(spec["components"]["schemas"]["SessionStart"])
    assert "409" in start["responses"]
    assert httpx.get(server.url + "/docs").status_code == 200


def test_cookie_login_logout_and_cross_site_changes(server: ServerProcess) -> None:
    with httpx.Client(base_url=server.url) as c:
        r = c.post(
            "/api/v1/auth/login", json={"login": "trainer", "password": PASSWORDS["trainer"]}
        )
        assert r.status_code == 200
        cookie = r.headers["set-cookie"].lower()
        assert "httponly" in cookie and "samesite=strict" in cookie
        assert c.get("/api/v1/auth/me").json()["via"] == "cookie"
        # a change from another site with the cookie is refused; from our own page it is fine
        evil = c.post(
            "/api/v1/users", json={"name": "X"}, headers={"Origin": "http://evil.example"}
        )
        assert evil.status_code == 403
        own = c.post("/api/v1/users", json={"name": "Y"}, headers={"Origin": server.url})
        assert own.status_code == 201
        assert c.post("/api/v1/auth/logout").status_code == 403  # no Origin: not our page
        out = c.post("/api/v1/auth/logout", headers={"Origin": server.url})
        assert out.status_code == 204
        gone = out.headers["set-cookie"].lower()  # deleted with the attributes it was set with
        assert "max-age=0" in gone and "httponly" in gone and "samesite=strict" in gone
        assert c.get("/api/v1/auth/me").status_code == 401


def test_failed_logins_are_rate_limited(server: ServerProcess) -> None:
    url = server.url + "/api/v1/auth/token"
    for _ in range(3):
        assert httpx.post(url, json={"login": "viewer", "password": "wrong"}).status_code == 401
    r = httpx.post(url, json={"login": "viewer", "password": PASSWORDS["viewer"]})
    assert r.status_code == 429 and int(r.headers["retry-after"]) >= 1


def test_revoked_token_and_disabled_account(server: ServerProcess, ids: dict[str, int]) -> None:
    token = httpx.post(
        server.url + "/api/v1/auth/token",
        json={"login": "spare", "password": "spare tyre in the boot"},
    ).json()["access_token"]
    h = {"Authorization": f"Bearer {token}"}
    assert httpx.get(server.url + "/api/v1/users", headers=h).status_code == 200
    with server.client("admin") as c:
        assert c.patch(f"/api/v1/accounts/{ids['acc']}", json={"disabled": True}).status_code == 200
    assert httpx.get(server.url + "/api/v1/users", headers=h).status_code == 401
    assert (
        httpx.get(
            server.url + "/api/v1/users", headers={"Authorization": "Bearer nope"}
        ).status_code
        == 401
    )


def test_live_websocket_checks_login_and_origin(server: ServerProcess) -> None:
    url = f"{server.ws_url}/api/v1/live"
    with pytest.raises(InvalidStatus):
        connect(url).close()  # anonymous
    with pytest.raises(InvalidStatus):
        connect(url, additional_headers={"Authorization": "Bearer forged"}).close()
    with pytest.raises(InvalidStatus):
        connect(
            url, additional_headers=server.headers("viewer"), origin="http://evil.example"
        ).close()
    with connect(url, additional_headers=server.headers("viewer"), origin=server.url) as ws:
        assert '"hello"' in ws.recv(timeout=10)
