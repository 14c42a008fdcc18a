"""Alembic environment of the store: runs on the connection the store passes in
``config.attributes["connection"]`` (see :mod:`sessions.store.migrate`)."""

from __future__ import annotations

from alembic import context
from sqlalchemy import Connection

from sessions.store.models import Base


def _run(connection: Connection) -> None:
    context.configure(
        connection=connection,
        target_metadata=Base.metadata,
        render_as_batch=connection.dialect.name == "sqlite",
        compare_type=True,
    )
    with context.begin_transaction():
        context.run_migrations()


def _main() -> None:
    config = context.config
    connection = config.attributes.get("connection")
    if context.is_offline_mode():
        context.configure(
            url=config.get_main_option("sqlalchemy.url"),
            target_metadata=Base.metadata,
            literal_binds=True,
        )
        with context.begin_transaction():
            context.run_migrations()
    elif connection is not None:
        _run(connection)
    else:
        from sessions.store.database import create_store_engine, database_url

        engine = create_store_engine(database_url(config.get_main_option("sqlalchemy.url")))
        try:
            with engine.begin() as conn:
                _run(conn)
        finally:
            engine.dispose()


_main()
