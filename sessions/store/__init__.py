"""The store: accounts, users, sessions with everything they recorded, per-user setpoints and
full-rate telemetry, in SQLite (default) or PostgreSQL, through SQLAlchemy 2 and Alembic.

All SQL lives in this package. Callers use :class:`Store` (or :func:`open_server_store` on
server start) and get plain records back. See ``docs/store.md``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from sessions.store.database import (
        DATA_DIR_ENV,
        DATABASE_URL_ENV,
        database_url,
        default_data_dir,
        display_url,
    )
    from sessions.store.errors import ConflictError, NotFoundError, StoreError, StoreValueError
    from sessions.store.recorder import SessionRecorder
    from sessions.store.records import (
        AccountRecord,
        EvaluationRecord,
        EventRecord,
        Page,
        PhaseRecord,
        PreferencesRecord,
        ProgressPoint,
        ProgressRecord,
        Role,
        SessionDetail,
        SessionRecord,
        SetpointRecord,
        TelemetryData,
        TelemetrySpan,
        TemplateRecord,
        TokenRecord,
        UserRecord,
    )
    from sessions.store.store import Store, open_server_store, open_store
    from sessions.store.templates import ForbiddenError
    from sessions.store.users import UNSET

# Each name from the module that defines it, imported on first use (PEP 562): a process that
# needs one part (the e-stop gate: the login tokens; the settings: the SQLite file's name)
# does not import the rest (Alembic, the recorder, the password checks).
_WHERE = {
    "DATA_DIR_ENV": "sessions.store.database",
    "DATABASE_URL_ENV": "sessions.store.database",
    "database_url": "sessions.store.database",
    "default_data_dir": "sessions.store.database",
    "display_url": "sessions.store.database",
    "ConflictError": "sessions.store.errors",
    "NotFoundError": "sessions.store.errors",
    "StoreError": "sessions.store.errors",
    "StoreValueError": "sessions.store.errors",
    "SessionRecorder": "sessions.store.recorder",
    "AccountRecord": "sessions.store.records",
    "EvaluationRecord": "sessions.store.records",
    "EventRecord": "sessions.store.records",
    "Page": "sessions.store.records",
    "PhaseRecord": "sessions.store.records",
    "PreferencesRecord": "sessions.store.records",
    "ProgressPoint": "sessions.store.records",
    "ProgressRecord": "sessions.store.records",
    "Role": "sessions.store.records",
    "SessionDetail": "sessions.store.records",
    "SessionRecord": "sessions.store.records",
    "SetpointRecord": "sessions.store.records",
    "TelemetryData": "sessions.store.records",
    "TelemetrySpan": "sessions.store.records",
    "TemplateRecord": "sessions.store.records",
    "TokenRecord": "sessions.store.records",
    "UserRecord": "sessions.store.records",
    "Store": "sessions.store.store",
    "open_server_store": "sessions.store.store",
    "open_store": "sessions.store.store",
    "ForbiddenError": "sessions.store.templates",
    "UNSET": "sessions.store.users",
}


def __getattr__(name: str) -> Any:
    where = _WHERE.get(name)
    if where is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(where), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_WHERE])


__all__ = [
    "DATABASE_URL_ENV",
    "DATA_DIR_ENV",
    "UNSET",
    "AccountRecord",
    "ConflictError",
    "EvaluationRecord",
    "EventRecord",
    "ForbiddenError",
    "NotFoundError",
    "Page",
    "PhaseRecord",
    "PreferencesRecord",
    "ProgressPoint",
    "ProgressRecord",
    "Role",
    "SessionDetail",
    "SessionRecord",
    "SessionRecorder",
    "SetpointRecord",
    "Store",
    "StoreError",
    "StoreValueError",
    "TelemetryData",
    "TelemetrySpan",
    "TemplateRecord",
    "TokenRecord",
    "UserRecord",
    "database_url",
    "default_data_dir",
    "display_url",
    "open_server_store",
    "open_store",
]
