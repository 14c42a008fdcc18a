"""Alembic, configured in code: the migrations live in ``sessions/store/migrations`` and no
``alembic.ini`` is needed. The store runs them on a connection of its own engine, inside one
transaction (SQLite and PostgreSQL both have transactional DDL), so a migration interrupted
by a crash leaves the previous revision in place.

For maintainers, a new revision after a model change::

    python -c "from sessions.store.migrate import new_revision; new_revision('add x')"

autogenerates it against ``$ERGOSEEK_DATABASE_URL`` (or the default file) upgraded to head;
read and tidy it before committing.
"""

from __future__ import annotations

from pathlib import Path

from alembic import command
from alembic.config import Config
from alembic.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Connection, Engine

MIGRATIONS = Path(__file__).resolve().parent / "migrations"


def alembic_config(connection: Connection | None = None) -> Config:
    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS))
    cfg.attributes["connection"] = connection
    return cfg


def head_revision() -> str:
    head = ScriptDirectory.from_config(alembic_config()).get_current_head()
    assert head is not None
    return head


def current_revision(engine: Engine) -> str | None:
    """The revision the database is at; None for an empty database."""
    with engine.connect() as conn:
        return MigrationContext.configure(conn).get_current_revision()


def upgrade(engine: Engine, revision: str = "head") -> None:
    with engine.begin() as conn:
        command.upgrade(alembic_config(conn), revision)


def downgrade(engine: Engine, revision: str) -> None:
    with engine.begin() as conn:
        command.downgrade(alembic_config(conn), revision)


def new_revision(message: str, url: str | None = None) -> None:
    """Autogenerate a revision from the models' difference with the database at ``url``."""
    from sessions.store.database import create_store_engine, database_url

    engine = create_store_engine(database_url(url))
    try:
        upgrade(engine)
        with engine.begin() as conn:
            command.revision(alembic_config(conn), message, autogenerate=True)
    finally:
        engine.dispose()
