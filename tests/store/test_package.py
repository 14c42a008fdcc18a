"""The store package's names, imported on first use: every name it exports is the one its
module defines, and a process that needs only the login tokens (the e-stop gate) or the
settings does not import Alembic, the recorder or the password checks."""

from __future__ import annotations

import importlib

import pytest

from sessions import store
from testing.processes import loaded_after


def test_every_exported_name_is_its_modules_own() -> None:
    assert sorted(store.__all__) == sorted(store._WHERE)
    for name, where in store._WHERE.items():
        assert getattr(store, name) is getattr(importlib.import_module(where), name), name
    with pytest.raises(AttributeError, match="no_such_name"):
        _ = store.no_such_name  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    "imports",
    [
        "from sessions.store.tokens import TokenRepository, digest\n"
        "from sessions.store.database import Database, database_url",
        "import server.settings",
    ],
)
def test_the_gates_and_the_settings_imports_stay_small(imports: str) -> None:
    heavy = ("alembic", "zxcvbn", "sessions.store.store", "sessions.store.recorder")
    assert loaded_after(imports, heavy) == []
