"""The password policy over REST and the CLI, and a lockout that a shared address cannot turn
against a known-good browser (issue 12.5). Against a real ``ergoseek serve``."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from testing.cli import ergoseek
from testing.server import PASSWORDS, ServerProcess, start_server

WEAK = ["12345678", "aaaaaaaa", " " * 8]


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> ServerProcess:
    env = {"ERGOSEEK_LOGIN_ATTEMPTS": "3"}
    with start_server(tmp_path_factory.mktemp("passwords"), env=env) as srv:
        yield srv


def _problem(r: httpx.Response) -> str:
    assert r.status_code == 422, r.text
    (item,) = r.json()["detail"]
    assert item["loc"] == ["body", "password"], item
    return str(item["msg"])


@pytest.mark.parametrize("password", [*WEAK, "boss-admin"])
def test_weak_passwords_and_the_login_are_refused_for_an_admin(
    server: ServerProcess, password: str
) -> None:
    with server.client("admin") as c:
        body = {"login": "boss-admin", "password": password, "role": "admin"}
        assert _problem(c.post("/api/v1/accounts", json=body))
        assert all(a["login"] != "boss-admin" for a in c.get("/api/v1/accounts").json())


def test_reasons_name_what_is_wrong(server: ServerProcess) -> None:
    with server.client("admin") as c:
        same = {"login": "coachy", "password": "Coachy2024!", "role": "trainer"}
        assert "login name" in _problem(c.post("/api/v1/accounts", json=same))
        short = {"login": "boss", "password": "vT9#qLm2xK!", "role": "admin"}
        assert "12" in _problem(c.post("/api/v1/accounts", json=short))
        short["role"] = "trainer"  # long enough for a trainer
        assert c.post("/api/v1/accounts", json=short).status_code == 201


def test_a_password_change_meets_the_policy(server: ServerProcess) -> None:
    with server.client("admin") as c:
        acc = c.post(
            "/api/v1/accounts",
            json={"login": "changer", "password": "orbit staple ninth", "role": "viewer"},
        ).json()
        for weak in WEAK:
            assert _problem(c.patch(f"/api/v1/accounts/{acc['id']}", json={"password": weak}))
        ok = c.patch(f"/api/v1/accounts/{acc['id']}", json={"password": "ninth orbit staple"})
        assert ok.status_code == 200
    r = httpx.post(
        server.url + "/api/v1/auth/token",
        json={"login": "changer", "password": "ninth orbit staple"},
    )
    assert r.status_code == 200


def test_the_cli_refuses_a_weak_password_in_one_line(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'db.sqlite3'}"
    for password in ("12345678", "rootroot1", "aaaaaaaaaaaaaa"):
        r = ergoseek("account", "create", "root", "--role", "admin", "--database-url", url,
                     stdin=password + "\n")  # fmt: skip
        assert r.returncode == 2, r.stdout
        assert r.stderr.count("\n") == 1 and "password" in r.stderr and "Traceback" not in r.stderr


def test_a_known_good_browser_is_not_locked_out_by_its_neighbours(server: ServerProcess) -> None:
    url = server.url + "/api/v1/auth/login"
    right = {"login": "trainer", "password": PASSWORDS["trainer"]}
    with httpx.Client(headers={"Origin": server.url}) as known:
        assert known.post(url, json=right).status_code == 200  # this browser: known-good now
        assert "ergoseek_device" in known.cookies
        # someone at the same address guesses, at this login and at others: the address locks
        for i in range(12):
            who = "trainer" if i % 2 else f"nobody{i}"
            httpx.post(url, json={"login": who, "password": f"guess-{i}"})
        assert httpx.post(url, json=right).status_code == 429  # an unknown client: locked
        # the known-good browser with the right password still gets in
        r = known.post(url, json=right)
        assert r.status_code == 200, r.text
        # and its own failures lock it (and only it)
        for _ in range(3):
            assert known.post(url, json={**right, "password": "wrong"}).status_code == 401
        assert known.post(url, json=right).status_code == 429
