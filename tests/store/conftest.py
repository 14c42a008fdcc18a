"""The store tests' fixtures: each test gets a fresh database on SQLite and on PostgreSQL
(a real server, :mod:`testing.postgres`), and a store at the newest schema in it."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from sessions.store import Store, open_store
from testing.postgres import postgres
from testing.store import FAST_HASHER

BACKENDS = ("sqlite", "postgresql")


def fresh_url(backend: str, tmp_path: Path) -> str:
    if backend == "sqlite":
        return f"sqlite:///{tmp_path / 'store.sqlite3'}"
    return postgres().create_database()


@pytest.fixture(params=BACKENDS)
def db_url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """The URL of a fresh, empty database on each backend (dropped afterwards)."""
    url = fresh_url(request.param, tmp_path)
    yield url
    if request.param == "postgresql":
        postgres().drop_database(url)


@pytest.fixture
def pg_url() -> Iterator[str]:
    """A fresh, empty PostgreSQL database (dropped afterwards)."""
    server = postgres()
    url = server.create_database()
    yield url
    server.drop_database(url)


@pytest.fixture
def store(db_url: str) -> Iterator[Store]:
    """A store at the newest schema in a fresh database."""
    st = open_store(db_url, password_hasher=FAST_HASHER)
    try:
        yield st
    finally:
        st.close()
