"""argon2id's cost: argon2-cffi's default unless the operator lowers it, never below OWASP's
minimum, the same for every new hash, and a hash of another cost stored again at the
server's own when it next lets its owner in."""

from __future__ import annotations

import re
import sqlite3
from pathlib import Path

import pytest
from argon2 import PasswordHasher
from pydantic import ValidationError

from server.settings import Settings
from sessions.store import open_store
from testing.cli import ergoseek
from testing.server import TEST_HASH_COST, start_server

PARAMS = re.compile(r"^\$argon2id\$v=19\$m=(\d+),t=(\d+),p=(\d+)\$")


def cost_of(digest: str) -> tuple[int, int, int]:
    m = PARAMS.match(digest)
    assert m, digest
    return int(m[1]), int(m[2]), int(m[3])


def stored(db: Path, login: str) -> tuple[int, int, int]:
    with sqlite3.connect(db) as c:
        (digest,) = c.execute(
            "select password_hash from accounts where login = ?", (login,)
        ).fetchone()
    return cost_of(digest)


def test_the_default_is_rfc_9106s_and_the_floor_owasps() -> None:
    hasher = Settings().password_hash.hasher()
    assert cost_of(hasher.hash("a password of some length")) == (65536, 3, 4)
    for key, low in (("memory_kib", 19 * 1024 - 1), ("time_cost", 1), ("parallelism", 0)):
        with pytest.raises(ValidationError, match=key):
            Settings(password_hash={key: low})


def test_serve_refuses_a_cost_below_the_floor_in_one_line(tmp_path: Path) -> None:
    conf = tmp_path / "weak.toml"
    conf.write_text("[password_hash]\nmemory_kib = 1024\n")
    proc = ergoseek("serve", "--config", str(conf), "--data-dir", str(tmp_path))
    assert proc.returncode == 2 and "memory_kib" in proc.stderr, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_new_hashes_have_the_servers_cost_and_old_ones_take_it_at_login(tmp_path: Path) -> None:
    db = tmp_path / "ergoseek.sqlite3"
    with open_store(f"sqlite:///{db}", password_hasher=PasswordHasher()) as store:
        store.accounts.create("elder", "an older password, kept", "viewer")
    want = (TEST_HASH_COST.memory_kib, TEST_HASH_COST.time_cost, TEST_HASH_COST.parallelism)
    assert want != (65536, 3, 4) and stored(db, "elder") == (65536, 3, 4)
    with start_server(tmp_path) as srv, srv.client("admin") as admin:
        body = {"login": "newer", "password": "a newer password, typed", "role": "viewer"}
        assert admin.post("/api/v1/accounts", json=body).status_code == 201
        assert stored(db, "newer") == want
        wrong = {"login": "elder", "password": "not the password at all"}
        assert admin.post("/api/v1/auth/token", json=wrong).status_code == 401
        assert stored(db, "elder") == (65536, 3, 4)  # a failed login changes nothing
        right = {"login": "elder", "password": "an older password, kept"}
        assert admin.post("/api/v1/auth/token", json=right).status_code == 200
        assert stored(db, "elder") == want
        assert admin.post("/api/v1/auth/token", json=right).status_code == 200  # still lets in
