"""``ergoseek db upgrade`` / ``ergoseek db current``: the store's schema.

The database is ``--url`` if given, else ``$ERGOSEEK_DATABASE_URL``, else the SQLite file in
the data directory (``$ERGOSEEK_DATA_DIR``, else ``$XDG_DATA_HOME/ergoseek``, else
``~/.local/share/ergoseek``). The server upgrades on start by itself; these are for
operators (and for checking before a deployment)."""

from __future__ import annotations

import argparse
from typing import Any


def register(sub: Any) -> None:
    p = sub.add_parser(
        "db",
        help="the store's database: upgrade the schema, show its revision",
        description="Manage the store's database schema (Alembic migrations shipped inside).",
    )
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    up = actions.add_parser("upgrade", help="migrate the database to the newest schema")
    up.add_argument("--revision", default="head", help="target revision (default: head)")
    cur = actions.add_parser("current", help="print the database's schema revision")
    for a in (up, cur):
        a.add_argument("--url", help="database URL (default: $ERGOSEEK_DATABASE_URL or the file)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from sqlalchemy.exc import SQLAlchemyError

    from server.cli import UsageError
    from sessions.store import StoreError, database_url, display_url
    from sessions.store.database import sqlite_path
    from sessions.store.migrate import head_revision
    from sessions.store.store import Store

    url = database_url(args.url)
    shown = display_url(url) if "://" in url else url
    try:
        if args.action == "current":
            path = sqlite_path(url)
            if path is not None and not path.expanduser().exists():
                raise UsageError(f"no database at {path} (run `ergoseek db upgrade` to create it)")
        with Store(url) as store:
            if args.action == "upgrade":
                store.upgrade(args.revision)
            rev = store.current_revision()
    except StoreError as exc:
        raise UsageError(f"{shown}: {exc}") from None
    except SQLAlchemyError as exc:
        detail = str(getattr(exc, "orig", None) or exc).splitlines()[0]
        raise UsageError(f"{shown}: {detail}") from None
    except Exception as exc:  # alembic: unknown revision and the like
        if type(exc).__module__.startswith("alembic"):
            raise UsageError(f"{shown}: {exc}") from None
        raise
    head = head_revision()
    state = "newest" if rev == head else f"newest is {head}"
    print(f"{shown}: revision {rev or 'none (empty)'} ({state})")
    return 0
