"""What the server refuses before any route runs (issue 12.2, 12.4, 12.6): bodies above the
limit (413, before they are read), anonymous bodies (401, before they are parsed), a Host that
is not ours, forwarded headers from a proxy nobody configured, a cookie write without an
Origin; and the headers of /docs. Against a real ``ergoseek serve`` over real sockets."""

from __future__ import annotations

import base64
import hashlib
import re

import httpx
import pytest

from testing.flood import MB, garbage, raw_request, request_head
from testing.server import PASSWORDS, ServerProcess, cpu_seconds, peak_rss_mb, start_server

LIMIT = 64 * 1024


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> ServerProcess:
    env = {"ERGOSEEK_LOGIN_ATTEMPTS": "3", "ERGOSEEK_MAX_BODY_BYTES": str(LIMIT)}
    with start_server(tmp_path_factory.mktemp("guard"), env=env) as srv:
        yield srv


def _head(server: ServerProcess, path: str, **headers: str) -> bytes:
    return request_head("POST", path, f"127.0.0.1:{server.port}", headers)


def test_a_50_mb_body_is_refused_before_it_is_read(server: ServerProcess) -> None:
    auth = {"Authorization": f"Bearer {server.token('trainer')}"}  # (argon2 takes 64 MiB)
    rss0 = peak_rss_mb(server.pid)
    for path, headers in (
        ("/api/v1/users", {**auth, "Content-Type": "application/json"}),  # a trainer's route
        ("/api/v1/auth/login", {"Content-Type": "application/json"}),  # the anonymous one
    ):
        # announced: refused on the headers alone, though not one byte of it is sent
        head = _head(server, path, **headers, **{"Content-Length": str(50 * MB)})
        r = raw_request(server.port, head, timeout=10)
        assert r.status == 413, (path, r)
        assert r.sent == 0
        # chunked (no length to look at): refused once past the limit, the rest never read
        head = _head(server, path, **headers, **{"Transfer-Encoding": "chunked"})
        r = raw_request(server.port, head, body_size=50 * MB, chunked=True, timeout=20)
        assert r.status == 413, (path, r)
        assert r.sent < 8 * MB, r  # the server stopped reading long before the end
    assert peak_rss_mb(server.pid) - rss0 < 30  # MiB: nothing like 50 MB was ever held


def test_an_anonymous_body_is_refused_before_it_is_read_or_parsed(server: ServerProcess) -> None:
    # under the limit, never sent: the answer cannot wait for it
    head = _head(server, "/api/v1/users", **{"Content-Length": "1000"})
    r = raw_request(server.port, head, timeout=10)
    assert r.status == 401 and r.seconds < 5, r
    # sent, and not JSON: 401 (who are you), not 422 (what is this)
    r = httpx.post(server.url + "/api/v1/users", content=b"{not json", timeout=10)
    assert r.status_code == 401, r.text
    # a forged bearer token is no login either
    r = httpx.post(
        server.url + "/api/v1/machine/estop",
        content=b"x" * 1000,
        headers={"Authorization": "Bearer forged"},
        timeout=10,
    )
    assert r.status_code == 401


def test_garbage_is_refused_cheaply(server: ServerProcess) -> None:
    cpu0 = cpu_seconds(server.pid)
    for i in range(200):
        garbage(server.port, bytes([i % 256]) * 512 + b"\r\n\r\n")
    assert httpx.get(server.url + "/healthz").json()["status"] == "ok"
    assert cpu_seconds(server.pid) - cpu0 < 5.0  # s of CPU for 200 refusals: nothing heavy


def test_a_foreign_host_is_refused_even_with_a_matching_origin(server: ServerProcess) -> None:
    with server.browser_client("trainer", PASSWORDS["trainer"]) as c:
        cookie = c.cookies["ergoseek_session"]
    headers = {
        "Host": "evil.example",
        "Origin": "http://evil.example",
        "Cookie": f"ergoseek_session={cookie}",
    }
    r = httpx.post(server.url + "/api/v1/users", json={"name": "Rebound"}, headers=headers)
    assert r.status_code == 400, r.text
    names = [u["name"] for u in server.client("viewer").get("/api/v1/users").json()["items"]]
    assert "Rebound" not in names
    # our own names still work: 127.0.0.1 and localhost, with the port
    for host in (f"127.0.0.1:{server.port}", f"localhost:{server.port}"):
        assert httpx.get(server.url + "/healthz", headers={"Host": host}).status_code == 200


def test_forwarded_for_is_not_trusted_unless_configured(server: ServerProcess) -> None:
    url = server.url + "/api/v1/auth/token"
    codes = []
    for i in range(30):
        h = {"X-Forwarded-For": f"203.0.113.{i}", "X-Real-IP": f"198.51.100.{i}"}
        codes.append(httpx.post(url, json={"login": "admin", "password": "wrong"}, headers=h))
    assert 429 in [r.status_code for r in codes]  # the limiter sees one address
    right = {"login": "admin", "password": PASSWORDS["admin"]}
    r = httpx.post(url, json=right, headers={"X-Forwarded-For": "192.0.2.77"})
    assert r.status_code == 429  # and the lockout is not bypassed by a header


def test_a_cookie_write_needs_an_origin(server: ServerProcess) -> None:
    with server.browser_client("trainer", PASSWORDS["trainer"]) as c:
        cookie = c.cookies["ergoseek_session"]
    bare = httpx.Client(base_url=server.url, headers={"Cookie": f"ergoseek_session={cookie}"})
    with bare:
        r = bare.post("/api/v1/machine/estop", headers={"Referer": "http://evil.example/"})
        assert r.status_code == 403, r.text
        assert bare.post("/api/v1/users", json={"name": "NoOrigin"}).status_code == 403
        assert bare.get("/api/v1/machine").status_code == 200  # reads need none
        own = bare.post("/api/v1/machine/reset", headers={"Origin": server.url})
        assert own.status_code == 202
    # a bearer token is never sent by a browser on its own: no Origin needed
    with server.client("trainer") as c:
        assert c.post("/api/v1/machine/reset").status_code == 202


def test_docs_are_served_locally_under_a_strict_policy(server: ServerProcess) -> None:
    r = httpx.get(server.url + "/docs")
    assert r.status_code == 200
    assert r.headers["x-frame-options"] == "DENY"
    csp = r.headers["content-security-policy"]
    assert "frame-ancestors 'none'" in csp and "'unsafe-inline'" not in csp.split("style-src")[0]
    scripts = re.findall(r'<script[^>]*src="([^"]+)"', r.text)
    assert scripts and all(s.startswith("/") for s in scripts)  # no CDN
    for href in re.findall(r'<link[^>]*href="([^"]+)"', r.text):
        assert href.startswith("/")
    for src in scripts:
        assert httpx.get(server.url + src).status_code == 200
    # every inline script is allowed by its hash, and nothing else inline is
    for body in re.findall(r"<script>(.*?)</script>", r.text, re.S):
        digest = hashlib.sha256(body.encode()).digest()
        assert f"'sha256-{base64.b64encode(digest).decode()}'" in csp


def test_api_responses_carry_the_safety_headers(server: ServerProcess) -> None:
    r = server.client("viewer").get("/api/v1/machine")
    assert r.headers["x-content-type-options"] == "nosniff"
    assert r.headers["x-frame-options"] == "DENY"
