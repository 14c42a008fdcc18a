"""The SQLite settings docs/store.md promises, read back from a real file with SQLite's own
``sqlite3`` module beside the store's connections (the independent reader):

- every connection: WAL, ``synchronous = FULL`` (a commit survives a power cut), foreign
  keys on, a 5 s busy timeout;
- a writing transaction takes the write lock at its ``BEGIN`` (``BEGIN IMMEDIATE``, sent
  with its first statement, a read here), so two writers queue on the busy timeout instead
  of one failing at its first write; a reading transaction takes none.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest
from sqlalchemy import text

from sessions.store import open_store
from sessions.store.database import BUSY_TIMEOUT_MS

FULL = 2  # PRAGMA synchronous: 0 OFF, 1 NORMAL, 2 FULL, 3 EXTRA


def test_every_connection_has_the_settings(tmp_path: Path) -> None:
    with (
        open_store(f"sqlite:///{tmp_path / 'db.sqlite3'}") as store,
        store._db.engine.connect() as cx,  # the store's own engine
    ):
        pragma = {
            name: cx.execute(text(f"PRAGMA {name}")).scalar()
            for name in ("journal_mode", "synchronous", "foreign_keys", "busy_timeout")
        }
    assert pragma == {
        "journal_mode": "wal",
        "synchronous": FULL,
        "foreign_keys": 1,
        "busy_timeout": BUSY_TIMEOUT_MS,
    }
    assert BUSY_TIMEOUT_MS == 5000  # the documented figure


def test_a_write_transaction_holds_the_lock_from_its_begin(tmp_path: Path) -> None:
    path = tmp_path / "db.sqlite3"
    with open_store(f"sqlite:///{path}") as store:
        other = sqlite3.connect(path, timeout=0.0, isolation_level=None)  # no waiting
        try:
            with store._db.session(write=True) as s:
                s.execute(text("SELECT 1"))  # its BEGIN, and a read: nothing written yet
                with pytest.raises(sqlite3.OperationalError, match="locked"):
                    other.execute("BEGIN IMMEDIATE")
            other.execute("BEGIN IMMEDIATE")  # released at its end
            other.execute("ROLLBACK")
            with store._db.session(write=False) as s:  # a reader locks nothing
                s.execute(text("SELECT 1"))
                other.execute("BEGIN IMMEDIATE")
                other.execute("ROLLBACK")
        finally:
            other.close()
