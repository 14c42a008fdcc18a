"""The tables, as SQLAlchemy 2.0 typed models. Only the store package sees these classes;
callers get the plain records of :mod:`sessions.store.records`.

Times of day are UTC (``UTCDateTime``); times within a session (``t``, ``t0``, ``t1``) are
seconds since the session started, like the ``t`` telemetry channel. Enumerations are
strings with a CHECK constraint (portable, and a new value is a one-line migration).
Deleting a user deletes their sessions and setpoints; deleting a session deletes its
evaluations, telemetry, events and phases; deleting an account keeps its sessions (started_by
NULL) and its shared protocol templates (no owner), and deletes its private templates and its
preferences.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

from sqlalchemy import (
    JSON,
    Boolean,
    CheckConstraint,
    DateTime,
    Double,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    MetaData,
    SmallInteger,
    String,
    Text,
    TypeDecorator,
    UniqueConstraint,
)
from sqlalchemy.engine import Dialect
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

from sessions.codes import BOUNDS, PHASE_KINDS, ROLES, STATUSES, TOKEN_KINDS
from sessions.units import VELOCITY_UNITS

NAMING = {
    "ix": "ix_%(table_name)s_%(column_0_N_name)s",
    "uq": "uq_%(table_name)s_%(column_0_N_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}


def _in(column: str, values: tuple[str, ...]) -> str:
    return f"{column} IN ({', '.join(repr(v) for v in values)})"


class UTCDateTime(TypeDecorator[datetime]):
    """An aware UTC datetime on the way out, whatever the database keeps: SQLite stores the
    naive UTC text, PostgreSQL a ``timestamp with time zone``. Naive input counts as UTC."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            value = value.replace(tzinfo=UTC)
        value = value.astimezone(UTC)
        return value.replace(tzinfo=None) if dialect.name == "sqlite" else value

    def process_result_value(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            return value.replace(tzinfo=UTC)
        return value.astimezone(UTC)


def utcnow() -> datetime:
    return datetime.now(UTC)


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING)


class Account(Base):
    """Someone who logs in to the server: an administrator, a trainer or a viewer."""

    __tablename__ = "accounts"
    __table_args__ = (CheckConstraint(_in("role", ROLES), name="role"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    login: Mapped[str] = mapped_column(String(64), unique=True)
    password_hash: Mapped[str] = mapped_column(String(256))
    role: Mapped[str] = mapped_column(String(16))
    disabled: Mapped[bool] = mapped_column(Boolean, default=False)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class User(Base):
    """The person exercising on the machine."""

    __tablename__ = "users"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(200), index=True)
    notes: Mapped[str] = mapped_column(Text, default="")
    body_mass_kg: Mapped[float | None] = mapped_column(Double)
    limb: Mapped[str | None] = mapped_column(String(64))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    # the simulated person (a sessions.config.UserConfig) that stands in for this user when
    # the machine is simulated; NULL for people who only use real hardware
    sim_profile: Mapped[dict[str, Any] | None] = mapped_column(JSON)


class ExerciseSession(Base):
    """One session on the machine: its configuration, state and summary. While it runs,
    the summary columns hold the live figures of the data stored so far."""

    __tablename__ = "sessions"
    __table_args__ = (
        CheckConstraint(_in("status", STATUSES), name="status"),
        CheckConstraint(_in("at_bound", BOUNDS), name="at_bound"),
        Index(None, "started_at", "id"),
        Index(None, "user_id", "started_at"),
        Index(None, "status"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"))
    account_id: Mapped[int | None] = mapped_column(
        ForeignKey("accounts.id", ondelete="SET NULL"), index=True
    )
    backend: Mapped[str] = mapped_column(String(32))
    config: Mapped[dict[str, Any]] = mapped_column(JSON)
    status: Mapped[str] = mapped_column(String(16), default="running")
    started_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    ended_at: Mapped[datetime | None] = mapped_column(UTCDateTime)
    seeker: Mapped[str] = mapped_column(String(32), default="")
    optimum_w: Mapped[float | None] = mapped_column(Double)
    optimum_p: Mapped[float | None] = mapped_column(Double)
    converged: Mapped[bool] = mapped_column(Boolean, default=False)
    mean_power: Mapped[float] = mapped_column(Double, default=0.0)
    peak_power: Mapped[float] = mapped_column(Double, default=0.0)
    work: Mapped[float] = mapped_column(Double, default=0.0)
    duration: Mapped[float] = mapped_column(Double, default=0.0)
    passivity_min: Mapped[float] = mapped_column(Double, default=0.0)
    evaluation_count: Mapped[int] = mapped_column(Integer, default=0)
    abort_reason: Mapped[str | None] = mapped_column(Text)
    # the search (issue 14): where it ended against the bracket, when and where it first
    # converged, the extremes of its targets, the regret (simulated users only)
    at_bound: Mapped[str | None] = mapped_column(String(8))
    optimum_t: Mapped[float | None] = mapped_column(Double)
    t_converged: Mapped[float | None] = mapped_column(Double)
    wd_converged: Mapped[float | None] = mapped_column(Double)
    p_converged: Mapped[float | None] = mapped_column(Double)
    target_min: Mapped[float | None] = mapped_column(Double)
    target_max: Mapped[float | None] = mapped_column(Double)
    regret: Mapped[float | None] = mapped_column(Double)


class SeekerEvaluation(Base):
    """One candidate the seeker measured: when, where, the mean power and its standard error
    (NULL when the seeker could not estimate it)."""

    __tablename__ = "seeker_evaluations"
    __table_args__ = (Index(None, "session_id", "t"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    session_id: Mapped[int] = mapped_column(ForeignKey("sessions.id", ondelete="CASCADE"))
    t: Mapped[float] = mapped_column(Double)
    candidate: Mapped[float] = mapped_column(Double)
    power: Mapped[float] = mapped_column(Double)
    stderr: Mapped[float | None] = mapped_column(Double)


class Setpoint(Base):
    """An optimal setpoint for a user; the current one is the newest accepted."""

    __tablename__ = "setpoints"
    __table_args__ = (Index(None, "user_id", "created_at"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"))
    velocity: Mapped[float] = mapped_column(Double)
    power: Mapped[float | None] = mapped_column(Double)
    seeker: Mapped[str] = mapped_column(String(32))
    session_id: Mapped[int | None] = mapped_column(
        ForeignKey("sessions.id", ondelete="SET NULL"), index=True
    )
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    accepted: Mapped[bool] = mapped_column(Boolean, default=True)


class TelemetryChunk(Base):
    """At most one second of full-rate telemetry, compressed (see :mod:`.codec`): ``n``
    samples from ``t0`` to ``t1`` inclusive; ``overview`` holds min/max pairs per block
    of samples for fast decimation."""

    __tablename__ = "telemetry_chunks"
    __table_args__ = (Index(None, "session_id", "t1"),)

    session_id: Mapped[int] = mapped_column(
        ForeignKey("sessions.id", ondelete="CASCADE"), primary_key=True
    )
    seq: Mapped[int] = mapped_column(Integer, primary_key=True)
    t0: Mapped[float] = mapped_column(Double)
    t1: Mapped[float] = mapped_column(Double)
    n: Mapped[int] = mapped_column(Integer)
    encoding: Mapped[int] = mapped_column(SmallInteger)
    payload: Mapped[bytes] = mapped_column(LargeBinary)
    overview: Mapped[bytes] = mapped_column(LargeBinary)


class Event(Base):
    """Something that happened in a session: a fault, an e-stop, a limit hit…"""

    __tablename__ = "events"
    __table_args__ = (Index(None, "session_id", "t"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    session_id: Mapped[int] = mapped_column(ForeignKey("sessions.id", ondelete="CASCADE"))
    t: Mapped[float] = mapped_column(Double)
    kind: Mapped[str] = mapped_column(String(32))
    detail: Mapped[dict[str, Any]] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class AuthToken(Base):
    """A login: a browser session (cookie) or an API client's bearer token. Only the SHA-256
    digest of the random token is stored, so a copy of the database logs nobody in."""

    __tablename__ = "auth_tokens"
    __table_args__ = (
        CheckConstraint(_in("kind", TOKEN_KINDS), name="kind"),
        Index(None, "expires_at"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    account_id: Mapped[int] = mapped_column(
        ForeignKey("accounts.id", ondelete="CASCADE"), index=True
    )
    digest: Mapped[str] = mapped_column(String(64), unique=True)
    kind: Mapped[str] = mapped_column(String(16))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    expires_at: Mapped[datetime] = mapped_column(UTCDateTime)
    revoked: Mapped[bool] = mapped_column(Boolean, default=False)


class SessionPhase(Base):
    """One phase of a session's protocol: when it ran (session seconds; ``t_end`` NULL while it
    runs) and its summary (NULL until it has ended); ``detail`` holds its stages, its work
    intervals (train) and its velocity-spectrum fit (profile)."""

    __tablename__ = "session_phases"
    __table_args__ = (
        CheckConstraint(_in("kind", PHASE_KINDS), name="kind"),
        CheckConstraint(_in("at_bound", BOUNDS), name="at_bound"),
        UniqueConstraint("session_id", "position"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    session_id: Mapped[int] = mapped_column(ForeignKey("sessions.id", ondelete="CASCADE"))
    position: Mapped[int] = mapped_column(Integer)  # index in the protocol (the stop: after)
    kind: Mapped[str] = mapped_column(String(16))
    name: Mapped[str] = mapped_column(String(100))
    t_start: Mapped[float] = mapped_column(Double)
    t_end: Mapped[float | None] = mapped_column(Double)
    planned_end: Mapped[float | None] = mapped_column(Double)
    mean_power: Mapped[float | None] = mapped_column(Double)
    peak_power: Mapped[float | None] = mapped_column(Double)
    work: Mapped[float | None] = mapped_column(Double)
    mean_w: Mapped[float | None] = mapped_column(Double)
    optimum_w: Mapped[float | None] = mapped_column(Double)
    at_bound: Mapped[str | None] = mapped_column(String(8))  # lower, upper (0005)
    detail: Mapped[dict[str, Any]] = mapped_column(JSON)


class ProtocolTemplate(Base):
    """A named protocol a trainer keeps: private to its owner, or shared with every account."""

    __tablename__ = "protocol_templates"
    __table_args__ = (Index(None, "shared", "name"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(100))
    description: Mapped[str] = mapped_column(Text, default="")
    protocol: Mapped[dict[str, Any]] = mapped_column(JSON)  # a sessions.protocol.config.Protocol
    account_id: Mapped[int | None] = mapped_column(
        ForeignKey("accounts.id", ondelete="SET NULL"), index=True
    )
    shared: Mapped[bool] = mapped_column(Boolean, default=False)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class AccountPreferences(Base):
    """How an account likes to read numbers (the API itself stays SI)."""

    __tablename__ = "account_preferences"
    __table_args__ = (CheckConstraint(_in("velocity_unit", VELOCITY_UNITS), name="velocity_unit"),)

    account_id: Mapped[int] = mapped_column(
        ForeignKey("accounts.id", ondelete="CASCADE"), primary_key=True
    )
    velocity_unit: Mapped[str] = mapped_column(String(8), default="rpm")
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
