"""Where the database is and how to talk to it: the URL (SQLite file by default), the engine
with its SQLite settings, and short transactions.

Data path: ``$ERGOSEEK_DATABASE_URL`` if set, else the SQLite file ``ergoseek.sqlite3`` in
``$ERGOSEEK_DATA_DIR``, else in ``$XDG_DATA_HOME/ergoseek``, else in
``~/.local/share/ergoseek``. A PostgreSQL URL (``postgresql://…`` or
``postgresql+psycopg://…``) selects PostgreSQL through psycopg 3.

Every SQLite connection runs with WAL, foreign keys on, ``synchronous = FULL`` (a commit
survives a power cut, not only a killed process) and a 5 s busy timeout. SQLAlchemy issues
``BEGIN`` itself: ``BEGIN IMMEDIATE`` for transactions that write (they queue on the busy
timeout instead of failing on a lock upgrade), a deferred ``BEGIN`` for reads (a WAL snapshot,
never blocked by the writer).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Any

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.engine import URL, make_url
from sqlalchemy.exc import ArgumentError
from sqlalchemy.orm import Session as OrmSession
from sqlalchemy.orm import sessionmaker

from sessions.store.errors import StoreValueError

DATA_DIR_ENV = "ERGOSEEK_DATA_DIR"
DATABASE_URL_ENV = "ERGOSEEK_DATABASE_URL"
SQLITE_FILENAME = "ergoseek.sqlite3"
BUSY_TIMEOUT_MS = 5000
_WRITE = "ergoseek_write"


def default_data_dir() -> Path:
    """``$ERGOSEEK_DATA_DIR``, else ``$XDG_DATA_HOME/ergoseek``, else
    ``~/.local/share/ergoseek``."""
    env = os.environ.get(DATA_DIR_ENV)
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_DATA_HOME")
    base = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / ".local" / "share"
    return base / "ergoseek"


def database_url(url: str | None = None) -> str:
    """The URL to use: ``url`` if given, else ``$ERGOSEEK_DATABASE_URL``, else the default file."""
    if url:
        return url
    env = os.environ.get(DATABASE_URL_ENV)
    if env:
        return env
    return f"sqlite:///{default_data_dir() / SQLITE_FILENAME}"


def parse_url(url: str) -> URL:
    """The URL as SQLAlchemy reads it, with ``postgresql://`` meaning psycopg 3; refuses URLs
    the store cannot use, naming the reason."""
    try:
        u = make_url(url)
    except ArgumentError as exc:
        raise StoreValueError("url", f"not a database URL ({exc})") from None
    backend = u.get_backend_name()
    if backend == "sqlite":
        if not u.database or u.database == ":memory:" or u.database.startswith("file::memory:"):
            raise StoreValueError("url", "in-memory SQLite is not supported: give a file path")
    elif backend == "postgresql":
        if u.drivername == "postgresql":
            u = u.set(drivername="postgresql+psycopg")
    else:
        raise StoreValueError("url", f"unsupported database {backend!r} (sqlite or postgresql)")
    return u


def display_url(url: str | URL) -> str:
    """The URL with any password hidden, for messages and logs."""
    u = url if isinstance(url, URL) else make_url(url)
    return u.render_as_string(hide_password=True)


def sqlite_path(url: str | URL) -> Path | None:
    """The database file of a SQLite URL, None for other databases."""
    u = url if isinstance(url, URL) else make_url(url)
    if u.get_backend_name() != "sqlite" or not u.database:
        return None
    return Path(u.database)


def _sqlite_settings(engine: Engine) -> None:
    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_conn: Any, _record: Any) -> None:
        dbapi_conn.isolation_level = None  # no implicit BEGIN from the driver: see _on_begin
        cur = dbapi_conn.cursor()
        cur.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
        cur.execute("PRAGMA foreign_keys = ON")
        cur.execute("PRAGMA journal_mode = WAL")
        cur.execute("PRAGMA synchronous = FULL")
        cur.close()

    @event.listens_for(engine, "begin")
    def _on_begin(conn: Any) -> None:
        write = conn.get_execution_options().get(_WRITE, False)
        conn.exec_driver_sql("BEGIN IMMEDIATE" if write else "BEGIN")


def create_store_engine(url: str) -> Engine:
    """An engine for ``url`` with the settings above; creates a SQLite file's directory."""
    u = parse_url(url)
    if u.get_backend_name() == "sqlite":
        path = sqlite_path(u)
        if path is not None:
            path.expanduser().parent.mkdir(parents=True, exist_ok=True)
        engine = create_engine(u, connect_args={"timeout": BUSY_TIMEOUT_MS / 1000})
        _sqlite_settings(engine)
        return engine
    return create_engine(u, pool_pre_ping=True)


# The transaction of Store.transaction() for the current thread or task, if any.
_CURRENT: ContextVar[tuple[Database, OrmSession] | None] = ContextVar(
    "ergoseek_store_transaction", default=None
)


class Database:
    """An engine plus short transactions. Repositories ask for ``session(write=…)``: inside
    :meth:`transaction` (or another repository call's writing session) they share its ORM
    session and its single commit; otherwise each call is its own transaction, committed on
    success and rolled back on any error."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.engine = create_store_engine(url)
        self.dialect = self.engine.dialect.name
        writer = self.engine.execution_options(**{_WRITE: True})
        self._read = sessionmaker(self.engine, expire_on_commit=False)
        self._write = sessionmaker(writer, expire_on_commit=False)

    @property
    def writer(self) -> Engine:
        """The engine whose SQLite transactions begin IMMEDIATE (for migrations)."""
        return self._write.kw["bind"]

    @contextmanager
    def session(self, *, write: bool) -> Iterator[OrmSession]:
        current = _CURRENT.get()
        if current is not None and current[0] is self:
            yield current[1]
            return
        if not write:
            with self._read.begin() as s:
                yield s
            return
        with self._write.begin() as s:  # repository calls made inside join it
            token = _CURRENT.set((self, s))
            try:
                yield s
            finally:
                _CURRENT.reset(token)

    @contextmanager
    def transaction(self) -> Iterator[None]:
        current = _CURRENT.get()
        if current is not None and current[0] is self:
            yield  # nested: part of the outer transaction
            return
        with self.session(write=True):
            yield

    def dispose(self) -> None:
        self.engine.dispose()
