"""The store: accounts, users, sessions with everything they recorded, per-user setpoints and
full-rate telemetry, in SQLite (default) or PostgreSQL, through SQLAlchemy 2 and Alembic.

All SQL lives in this package. Callers use :class:`Store` (or :func:`open_server_store` on
server start) and get plain records back. See ``docs/store.md``.
"""

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
