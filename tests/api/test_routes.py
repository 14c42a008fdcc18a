"""Every route the app has, from the app itself, against one table of who may call it.

The inventory is :func:`server.app.create_app`'s own routes (REST, WebSocket, mounted apps,
the dashboard's pages and proxy), flattened. :data:`TABLE` holds, for each, the least role it
needs (docs/server.md's role matrix; ``None``: public), the request to send and the answer a
role that may call it gets. A route the app has and the table does not (a new route), or an
entry for a route the app no longer has, fails :func:`test_the_table_covers_every_route`;
every entry is checked against a real server (with its dashboard): anonymous → 401 (or the
documented refusal), each role below the least → 403 and nothing changed, each role at or
above → exactly the documented answer.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import httpx
import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from server.api.workflow_schemas import TEMPLATE_EXAMPLE
from server.app import create_app
from server.security import COOKIE
from server.settings import Settings
from testing.server import ACCOUNTS, ServerProcess
from testing.viser_wire import SUBPROTOCOL

ROLES = ("viewer", "trainer", "admin")
RANK = {"viewer": 0, "trainer": 1, "admin": 2}
WS_REFUSED = 403  # a WebSocket refused before accept: Starlette answers the handshake 403


@dataclass(frozen=True)
class Rule:
    """Who may call a route and what they get. ``path`` is filled from the fixture's ids
    (``{user}``, ``{acc}``, ``{sid}``, made fresh per call where the call consumes them);
    ``ok`` is the status a permitted role gets; ``anon`` what a request without a login
    gets; ``still`` a check (given the admin's client) that a refused call changed nothing."""

    least: str | None
    path: str
    ok: int
    body: dict[str, Any] | None = None
    anon: int = 401
    still: str | None = None  # a GET that must still answer 200 after a refused call
    cookie: bool = False  # a browser's route: the login cookie, not a bearer token


# (method, route path as the app declares it) → the rule
TABLE: dict[tuple[str, str], Rule] = {
    ("GET", "/openapi.json"): Rule(None, "/openapi.json", 200, anon=200),
    ("GET", "/docs"): Rule(None, "/docs", 200, anon=200),
    ("MOUNT", "/docs/static"): Rule(None, "/docs/static/swagger-ui.css", 200, anon=200),
    ("GET", "/healthz"): Rule(None, "/healthz", 200, anon=200),
    ("POST", "/api/v1/auth/login"): Rule(None, "/api/v1/auth/login", 200, anon=200),
    ("POST", "/api/v1/auth/token"): Rule(None, "/api/v1/auth/token", 200, anon=200),
    ("POST", "/api/v1/auth/logout"): Rule("viewer", "/api/v1/auth/logout", 204),
    ("GET", "/api/v1/auth/me"): Rule("viewer", "/api/v1/auth/me", 200),
    ("GET", "/api/v1/accounts"): Rule("admin", "/api/v1/accounts", 200),
    ("POST", "/api/v1/accounts"): Rule(
        "admin", "/api/v1/accounts", 201, {"password": "a long spare pass phrase", "role": "viewer"}
    ),
    ("GET", "/api/v1/accounts/{account_id}"): Rule("admin", "/api/v1/accounts/{acc}", 200),
    ("PATCH", "/api/v1/accounts/{account_id}"): Rule(
        "admin", "/api/v1/accounts/{acc}", 200, {"disabled": True}
    ),
    ("DELETE", "/api/v1/accounts/{account_id}"): Rule(
        "admin", "/api/v1/accounts/{acc}", 204, still="/api/v1/accounts/{acc}"
    ),
    ("GET", "/api/v1/users"): Rule("viewer", "/api/v1/users", 200),
    ("POST", "/api/v1/users"): Rule("trainer", "/api/v1/users", 201, {"name": "Zed"}),
    ("GET", "/api/v1/users/{user_id}"): Rule("viewer", "/api/v1/users/{user}", 200),
    ("PATCH", "/api/v1/users/{user_id}"): Rule(
        "trainer", "/api/v1/users/{user}", 200, {"notes": "ok"}
    ),
    ("DELETE", "/api/v1/users/{user_id}"): Rule(
        "trainer", "/api/v1/users/{user}", 204, still="/api/v1/users/{user}"
    ),
    ("GET", "/api/v1/users/{user_id}/setpoints"): Rule(
        "viewer", "/api/v1/users/{user}/setpoints", 200
    ),
    ("POST", "/api/v1/users/{user_id}/setpoints"): Rule(
        "trainer", "/api/v1/users/{user}/setpoints", 201, {"velocity": 3.0}
    ),
    # a start for an unknown user: 404 once allowed (a real start is tested elsewhere)
    ("POST", "/api/v1/sessions"): Rule("trainer", "/api/v1/sessions", 404, {"user_id": 999999}),
    ("GET", "/api/v1/sessions"): Rule("viewer", "/api/v1/sessions", 200),
    ("GET", "/api/v1/sessions/{session_id}"): Rule("viewer", "/api/v1/sessions/{sid}", 200),
    # the session has ended: allowed, the stop is refused as not running
    ("POST", "/api/v1/sessions/{session_id}/stop"): Rule(
        "trainer", "/api/v1/sessions/{sid}/stop", 409
    ),
    ("GET", "/api/v1/sessions/{session_id}/events"): Rule(
        "viewer", "/api/v1/sessions/{sid}/events", 200
    ),
    ("GET", "/api/v1/sessions/{session_id}/telemetry"): Rule(
        "viewer", "/api/v1/sessions/{sid}/telemetry", 200
    ),
    ("GET", "/api/v1/sessions/{session_id}/telemetry.csv"): Rule(
        "viewer", "/api/v1/sessions/{sid}/telemetry.csv", 200
    ),
    # the trainer's workflow (issue 15): templates (a shared one, which every trainer may
    # edit), previews, a session's phases, its report and activity file, progress, overlay,
    # one's own display preferences
    ("GET", "/api/v1/protocols"): Rule("viewer", "/api/v1/protocols", 200),
    ("POST", "/api/v1/protocols"): Rule("trainer", "/api/v1/protocols", 201, TEMPLATE_EXAMPLE),
    ("POST", "/api/v1/protocols/preview"): Rule(
        "viewer", "/api/v1/protocols/preview", 200, {"protocol": TEMPLATE_EXAMPLE["protocol"]}
    ),
    ("GET", "/api/v1/protocols/{template_id}"): Rule("viewer", "/api/v1/protocols/{tpl}", 200),
    ("PATCH", "/api/v1/protocols/{template_id}"): Rule(
        "trainer", "/api/v1/protocols/{tpl}", 200, {"description": "edited"}
    ),
    ("DELETE", "/api/v1/protocols/{template_id}"): Rule(
        "trainer", "/api/v1/protocols/{tpl}", 204, still="/api/v1/protocols/{tpl}"
    ),
    ("GET", "/api/v1/sessions/{session_id}/phases"): Rule(
        "viewer", "/api/v1/sessions/{sid}/phases", 200
    ),
    ("GET", "/api/v1/sessions/{session_id}/report.pdf"): Rule(
        "viewer", "/api/v1/sessions/{sid}/report.pdf", 200
    ),
    ("GET", "/api/v1/sessions/{session_id}/activity.fit"): Rule(
        "viewer", "/api/v1/sessions/{sid}/activity.fit", 200
    ),
    ("GET", "/api/v1/sessions/{session_id}/overlay"): Rule(
        "viewer", "/api/v1/sessions/{sid}/overlay?with={sid}", 200
    ),
    ("GET", "/api/v1/users/{user_id}/progress"): Rule(
        "viewer", "/api/v1/users/{user}/progress", 200
    ),
    ("GET", "/api/v1/accounts/me/preferences"): Rule(
        "viewer", "/api/v1/accounts/me/preferences", 200
    ),
    ("PUT", "/api/v1/accounts/me/preferences"): Rule(
        "viewer", "/api/v1/accounts/me/preferences", 200, {"velocity_unit": "rpm"}
    ),
    ("GET", "/api/v1/machine"): Rule("viewer", "/api/v1/machine", 200),
    ("POST", "/api/v1/machine/estop"): Rule("trainer", "/api/v1/machine/estop", 202),
    ("POST", "/api/v1/machine/reset"): Rule("trainer", "/api/v1/machine/reset", 202),
    ("WS", "/api/v1/live"): Rule("viewer", "/api/v1/live", 101, anon=WS_REFUSED),
    # the dashboard: the login page is public; its client needs a login (anonymous: sent
    # to the login page); its socket a login (refused before accept)
    ("GET", "/"): Rule(None, "/", 200, anon=200),
    ("GET", "/dashboard"): Rule(None, "/dashboard", 307, anon=307),
    ("GET", "/dashboard/{relpath:path}"): Rule("viewer", "/dashboard/", 200, anon=303, cookie=True),
    ("WS", "/dashboard"): Rule("viewer", "/dashboard", 101, anon=WS_REFUSED),
}


def app_routes() -> set[tuple[str, str]]:
    """(method, path) of every route the app serves: FastAPI's included routers flattened,
    WebSocket routes as ``WS``, mounted apps as ``MOUNT``."""
    app = create_app(Settings(dashboard=True))
    found: set[tuple[str, str]] = set()
    for route in app.routes:
        expand = getattr(route, "effective_route_contexts", None)
        for ctx in expand() if expand is not None else [route]:
            original = getattr(ctx, "original_route", ctx)
            path = getattr(ctx, "path", "") or getattr(original, "path", "")
            kind = type(original).__name__
            if "WebSocket" in kind:
                found.add(("WS", path))
            elif kind == "Mount":
                found.add(("MOUNT", path))
            else:
                methods = set(getattr(ctx, "methods", None) or ()) - {"HEAD"}
                assert methods, f"a route without methods: {kind} {path}"
                found.update((m, path) for m in methods)
    return found


def test_the_table_covers_every_route() -> None:
    routes = app_routes()
    assert len(routes) >= 35  # the inventory itself works (REST, WS, mounts, dashboard)
    missing = sorted(routes - TABLE.keys())
    assert not missing, f"routes with no entry in TABLE (who may call them?): {missing}"
    stale = sorted(TABLE.keys() - routes)
    assert not stale, f"TABLE entries for routes the app does not have: {stale}"


# -- the checks against a real server -----------------------------------------------------------
@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    srv = ServerProcess(tmp_path_factory.mktemp("routes"), "serve", [], list(ACCOUNTS))
    with srv.start():
        yield srv


@pytest.fixture(scope="module")
def session_id(server: ServerProcess) -> int:
    """A session that ran and ended (its telemetry, events and summary are real)."""
    with server.client("admin") as c:
        user = c.post("/api/v1/users", json={"name": "Runner"}).json()["id"]
        r = c.post("/api/v1/sessions", json={"user_id": user, "duration": 0.5})
        assert r.status_code == 201, r.text
        sid = int(r.json()["id"])
    body = server.wait_status(sid, {"completed", "stopped", "aborted", "faulted"}, 30.0)
    assert body["session"]["status"] == "completed", body["session"]
    return sid


_SERIAL = itertools.count(1)


class Ids:
    """Fresh ids for a call (a user or account to delete, a session that ran)."""

    def __init__(self, server: ServerProcess, sid: int) -> None:
        self.server, self.sid, self.n = server, sid, 0

    def fill(self, path: str) -> str:
        self.n = next(_SERIAL)
        ids: dict[str, int] = {"sid": self.sid}
        with self.server.client("admin") as c:
            if "{user}" in path:
                ids["user"] = c.post("/api/v1/users", json={"name": f"U{self.n}"}).json()["id"]
            if "{tpl}" in path:
                made = {**TEMPLATE_EXAMPLE, "name": f"T{self.n}"}
                ids["tpl"] = c.post("/api/v1/protocols", json=made).json()["id"]
            if "{acc}" in path:
                ids["acc"] = c.post(
                    "/api/v1/accounts",
                    json={"login": f"spare{self.n}", "password": "spare tyre in the boot"},
                ).json()["id"]
        return path.format(**ids)


def _body(rule: Rule, ids: Ids, role: str | None) -> dict[str, Any] | None:
    if rule.path in ("/api/v1/auth/login", "/api/v1/auth/token"):
        login = role or "viewer"
        return {"login": login, "password": {a: p for a, p, _ in ACCOUNTS}[login]}
    if rule.path == "/api/v1/accounts":
        return {**(rule.body or {}), "login": f"new{ids.n}x{role}"}
    if rule.path == "/api/v1/protocols":  # template names are unique
        return {**(rule.body or {}), "name": f"T{ids.n}x{role}"}
    return rule.body


def _fresh_token(server: ServerProcess, role: str) -> dict[str, str]:
    """A login of its own (logout ends the login it is called with)."""
    r = httpx.post(
        f"{server.url}/api/v1/auth/token",
        json={"login": role, "password": server.passwords()[role]},
        timeout=20.0,
    )
    r.raise_for_status()
    return {"Authorization": f"Bearer {r.json()['access_token']}"}


def _cookie(server: ServerProcess, role: str) -> dict[str, str]:
    """A browser's login: the cookie ``POST /auth/login`` sets."""
    r = httpx.post(
        f"{server.url}/api/v1/auth/login",
        json={"login": role, "password": server.passwords()[role]},
        timeout=20.0,
    )
    r.raise_for_status()
    return {"Cookie": f"{COOKIE}={r.cookies[COOKIE]}"}


def _http(server: ServerProcess, method: str, url: str, body: Any, headers: dict) -> int:
    m = "GET" if method == "MOUNT" else method
    r = httpx.request(
        m, server.url + url, json=body, headers=headers, timeout=20.0, follow_redirects=False
    )
    assert r.status_code < 500, (method, url, r.status_code, r.text)
    return r.status_code


def _ws(server: ServerProcess, url: str, headers: dict[str, str]) -> int:
    protocols = [SUBPROTOCOL] if url == "/dashboard" else None
    try:
        with connect(
            server.ws_url + url,
            additional_headers=headers,
            subprotocols=protocols,  # type: ignore[arg-type]
            open_timeout=10,
        ) as ws:
            if url == "/api/v1/live":
                assert '"hello"' in str(ws.recv(timeout=10))
            return 101
    except InvalidStatus as exc:
        return exc.response.status_code


def _call(server: ServerProcess, method: str, rule: Rule, ids: Ids, role: str | None) -> int:
    url = ids.fill(rule.path)
    headers: dict[str, str] = {}
    if role is not None:
        fresh = method == "POST" and rule.path == "/api/v1/auth/logout"
        headers = _fresh_token(server, role) if fresh else server.headers(role)
        headers = _cookie(server, role) if rule.cookie else headers
    if method == "WS":
        return _ws(server, url, headers)
    status = _http(server, method, url, _body(rule, ids, role), headers)
    if rule.still is not None and status in (401, 403):
        still = rule.still.format_map(_Same(url, rule.path))
        with server.client("admin") as c:
            assert c.get(still).status_code == 200, f"a refused {method} {url} changed {still}"
    return status


class _Same(dict):  # type: ignore[type-arg]
    """The ids a refused call used, read back from its URL (for ``Rule.still``)."""

    def __init__(self, url: str, template: str) -> None:
        super().__init__()
        for part, tpl in zip(url.split("/"), template.split("/"), strict=True):
            if tpl.startswith("{"):
                self[tpl[1:-1]] = part


def _after(server: ServerProcess, method: str, path: str) -> None:
    """Undo what an allowed call latched (an e-stop)."""
    if (method, path) == ("POST", "/api/v1/machine/estop"):
        with server.client("admin") as c:
            assert c.post("/api/v1/machine/reset").status_code == 202


@pytest.mark.parametrize(("method", "path"), sorted(TABLE), ids=str)
def test_every_route_answers_each_role_as_documented(
    server: ServerProcess, session_id: int, method: str, path: str
) -> None:
    _check(server, session_id, method, path)


ESTOP = ("POST", "/api/v1/machine/estop")


def test_the_estop_route_without_its_gate(tmp_path_factory: pytest.TempPathFactory) -> None:
    """With its gate (the default) the gate answers an e-stop; without it the API route
    does, and checks the same roles."""
    srv = ServerProcess(
        tmp_path_factory.mktemp("nogate"),
        "serve",
        ["--no-dashboard"],
        list(ACCOUNTS),
        {"ERGOSEEK_ESTOP_GATE": "false"},
    )
    with srv.start():
        _check(srv, 0, *ESTOP)


def _check(server: ServerProcess, session_id: int, method: str, path: str) -> None:
    rule = TABLE[(method, path)]
    ids = Ids(server, session_id)
    check: Callable[[str | None], int] = lambda role: _call(server, method, rule, ids, role)  # noqa: E731
    assert check(None) == rule.anon, ("anonymous", method, path)
    for role in ROLES:
        got = check(role)
        if rule.least is not None and RANK[role] < RANK[rule.least]:
            assert got == 403, (role, method, path, got)
        else:
            assert got == rule.ok, (role, method, path, got)
            _after(server, method, path)
