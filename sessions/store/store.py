"""The store as one object: repositories over one database, migrations, crash recovery."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager

from argon2 import PasswordHasher
from sqlalchemy import text

from sessions.store import migrate
from sessions.store.accounts import AccountRepository
from sessions.store.database import Database, database_url, display_url
from sessions.store.errors import StoreError
from sessions.store.phases import PhaseRepository
from sessions.store.preferences import PreferencesRepository
from sessions.store.progress import ProgressRepository
from sessions.store.recorder import SessionRecorder
from sessions.store.sessions import RESTART_REASON, SessionRepository
from sessions.store.setpoints import SetpointRepository
from sessions.store.templates import TemplateRepository
from sessions.store.timeseries import TelemetryRepository
from sessions.store.tokens import TokenRepository
from sessions.store.users import UserRepository

log = logging.getLogger(__name__)


class Store:
    """Accounts (and their preferences), users, sessions (with evaluations, events and
    phases), setpoints, telemetry and protocol templates in one database. Thread-safe; every
    call is its own short transaction unless made inside :meth:`transaction`. Returns plain
    records, never ORM objects."""

    def __init__(self, url: str | None = None, *, password_hasher: PasswordHasher | None = None):
        self.url = database_url(url)
        self._db = Database(self.url)
        self.accounts = AccountRepository(self._db, password_hasher or PasswordHasher())
        self.users = UserRepository(self._db)
        self.sessions = SessionRepository(self._db)
        self.setpoints = SetpointRepository(self._db)
        self.telemetry = TelemetryRepository(self._db)
        self.tokens = TokenRepository(self._db)
        self.phases = PhaseRepository(self._db)
        self.templates = TemplateRepository(self._db)
        self.preferences = PreferencesRepository(self._db)
        self.progress = ProgressRepository(self._db)

    @property
    def dialect(self) -> str:
        """``sqlite`` or ``postgresql``."""
        return self._db.dialect

    def __repr__(self) -> str:
        return f"Store({display_url(self.url)!r})"

    @contextmanager
    def transaction(self) -> Iterator[None]:
        """Make the store calls inside one transaction: all committed at the end, or none if
        anything raises."""
        with self._db.transaction():
            yield

    def recorder(
        self, session_id: int, *, flush_interval: float = 0.5, background: bool = True
    ) -> SessionRecorder:
        """The writer a running session is fed through (see :class:`SessionRecorder`)."""
        return SessionRecorder(
            self._db, session_id, flush_interval=flush_interval, background=background
        )

    def current_revision(self) -> str | None:
        return migrate.current_revision(self._db.engine)

    def upgrade(self, revision: str = "head") -> None:
        migrate.upgrade(self._db.writer, revision)

    def downgrade(self, revision: str) -> None:
        migrate.downgrade(self._db.writer, revision)

    def check(self) -> list[str]:
        """Problems found in the database; empty when healthy (SQLite: ``integrity_check``
        and ``foreign_key_check``; PostgreSQL: the connection answers)."""
        with self._db.engine.connect() as conn:
            if self.dialect != "sqlite":
                conn.execute(text("SELECT 1"))
                return []
            found = [r[0] for r in conn.execute(text("PRAGMA integrity_check"))]
            problems = [] if found == ["ok"] else found
            problems += [
                f"foreign key: {r[0]} row {r[1]} -> {r[2]}"
                for r in conn.execute(text("PRAGMA foreign_key_check"))
            ]
            return problems

    def close(self) -> None:
        self._db.dispose()

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_store(
    url: str | None = None,
    *,
    upgrade: bool = True,
    password_hasher: PasswordHasher | None = None,
) -> Store:
    """The store at ``url`` (default: ``$ERGOSEEK_DATABASE_URL`` or the SQLite file in the
    data directory), migrated to the newest schema; with ``upgrade=False``, a database not at
    the newest schema is refused."""
    store = Store(url, password_hasher=password_hasher)
    try:
        if upgrade:
            store.upgrade()
        else:
            have, want = store.current_revision(), migrate.head_revision()
            if have != want:
                raise StoreError(
                    f"database {display_url(store.url)} is at revision {have or 'none'}, "
                    f"not {want}: run `ergoseek db upgrade`"
                )
    except BaseException:
        store.close()
        raise
    return store


def open_server_store(
    url: str | None = None,
    *,
    reason: str = RESTART_REASON,
    password_hasher: PasswordHasher | None = None,
) -> tuple[Store, list[int]]:
    """What the server calls on start: open, upgrade to the newest schema, and mark sessions
    left running by a previous process as aborted with ``reason``. Returns the store and the
    ids of the sessions it aborted."""
    store = open_store(url, upgrade=True, password_hasher=password_hasher)
    try:
        aborted = store.sessions.recover(reason)
    except BaseException:
        store.close()
        raise
    if aborted:
        log.warning("marked %d interrupted session(s) aborted: %s", len(aborted), aborted)
    return store, aborted
