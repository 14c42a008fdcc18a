"""What the store hands back: plain, frozen pydantic records (and one numpy container),
detached from any database session. Times of day are aware UTC datetimes."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from typing import Any, Generic, TypeVar

import numpy as np
from pydantic import BaseModel, ConfigDict

from sessions.codes import Bound, PhaseKindName, Role, SessionStatus, TokenKind
from sessions.config import SessionConfig
from sessions.summary import SessionSummary
from sessions.telemetry import INDEX
from sessions.units import VelocityUnit

T = TypeVar("T")


class Record(BaseModel):
    model_config = ConfigDict(frozen=True, from_attributes=True)


class AccountRecord(Record):
    id: int
    login: str
    role: Role
    disabled: bool
    created_at: datetime


class TokenRecord(Record):
    """A login (browser cookie or bearer token); the token itself is never stored."""

    id: int
    account_id: int
    kind: TokenKind
    created_at: datetime
    expires_at: datetime
    revoked: bool


class UserRecord(Record):
    id: int
    name: str
    notes: str
    body_mass_kg: float | None
    limb: str | None
    created_at: datetime
    updated_at: datetime
    sim_profile: dict[str, Any] | None = None  # a sessions.config.UserConfig, for simulation


class SessionRecord(Record):
    """A session and its summary (live figures while it runs)."""

    id: int
    user_id: int
    account_id: int | None
    backend: str
    config: dict[str, Any]
    status: SessionStatus
    started_at: datetime
    ended_at: datetime | None
    seeker: str
    optimum_w: float | None
    optimum_p: float | None
    converged: bool
    mean_power: float
    peak_power: float
    work: float
    duration: float
    passivity_min: float
    evaluation_count: int
    abort_reason: str | None
    at_bound: Bound | None = None
    optimum_t: float | None = None
    t_converged: float | None = None
    wd_converged: float | None = None
    p_converged: float | None = None
    target_min: float | None = None
    target_max: float | None = None
    regret: float | None = None

    def summary(self) -> SessionSummary:
        return SessionSummary(
            optimum_w=self.optimum_w,
            optimum_p=self.optimum_p,
            optimum_t=self.optimum_t,
            converged=self.converged,
            at_bound=self.at_bound,
            t_converged=self.t_converged,
            wd_converged=self.wd_converged,
            p_converged=self.p_converged,
            target_min=self.target_min,
            target_max=self.target_max,
            regret=self.regret,
            seeker=self.seeker,
            mean_power=self.mean_power,
            peak_power=self.peak_power,
            work=self.work,
            duration=self.duration,
            passivity_min=self.passivity_min,
            evaluations=self.evaluation_count,
            abort_reason=self.abort_reason,
        )

    def session_config(self) -> SessionConfig:
        return SessionConfig.model_validate(self.config)


class PhaseRecord(Record):
    """One phase of a session (session seconds; the summary None until the phase has ended)."""

    id: int
    session_id: int
    position: int
    kind: PhaseKindName
    name: str
    t_start: float
    t_end: float | None
    planned_end: float | None
    mean_power: float | None
    peak_power: float | None
    work: float | None
    mean_w: float | None
    optimum_w: float | None
    at_bound: Bound | None = None  # the phase's optimum is the bracket's edge (seek, train)
    detail: dict[str, Any]


class TemplateRecord(Record):
    """A protocol template: ``account_id`` its owner (None: the owner's account is gone)."""

    id: int
    name: str
    description: str
    protocol: dict[str, Any]
    account_id: int | None
    shared: bool
    created_at: datetime
    updated_at: datetime


class PreferencesRecord(Record):
    account_id: int
    velocity_unit: VelocityUnit
    updated_at: datetime | None = None


class ProgressPoint(Record):
    """One session on a user's progress chart (SI units)."""

    session_id: int
    started_at: datetime
    status: SessionStatus
    protocol: str  # the protocol's name ("" without one)
    seeker: str
    converged: bool
    at_bound: Bound | None
    optimum_w: float | None  # the optimum at the end (what was stored), rad/s
    optimum_p: float | None
    optimum_t: float | None
    wd_converged: float | None  # the optimum first found, and when
    t_converged: float | None
    mean_power: float
    peak_power: float
    work: float
    duration: float
    profiles: list[dict[str, Any]] = []  # the profile phases' fits: tau0, wmax, pmax, w_opt, a


class ProgressRecord(Record):
    user_id: int
    body_mass_kg: float | None
    sessions: list[ProgressPoint]


class EvaluationRecord(Record):
    """A measured candidate; ``stderr`` is None where the seeker had no estimate (∞)."""

    id: int
    session_id: int
    t: float
    candidate: float
    power: float
    stderr: float | None


class EventRecord(Record):
    id: int
    session_id: int
    t: float
    kind: str
    detail: dict[str, Any]
    created_at: datetime


class SetpointRecord(Record):
    id: int
    user_id: int
    velocity: float
    power: float | None
    seeker: str
    session_id: int | None
    created_at: datetime
    accepted: bool


class SessionDetail(Record):
    """One session's summary with everything its seeker measured, every event and its phases."""

    session: SessionRecord
    evaluations: list[EvaluationRecord]
    events: list[EventRecord]
    phases: list[PhaseRecord] = []


class Page(BaseModel, Generic[T]):
    """One page of a list in a stable order, with the number of matches over all pages."""

    model_config = ConfigDict(frozen=True)

    items: list[T]
    total: int
    limit: int
    offset: int


class TelemetrySpan(Record):
    """What a session's telemetry covers, without decoding it."""

    samples: int
    chunks: int
    t0: float | None
    t1: float | None
    stored_bytes: int


@dataclass(frozen=True, slots=True)
class TelemetryData:
    """Telemetry of one session: ``columns`` is (channels, samples) float64 in the order of
    :data:`sessions.telemetry.CHANNELS`. ``decimated`` says whether these are min/max pairs
    of buckets rather than the samples themselves; ``samples`` counts the full-rate samples
    of the time window either way."""

    columns: np.ndarray
    decimated: bool
    samples: int

    @property
    def rows(self) -> np.ndarray:
        """(samples, channels), a view."""
        return self.columns.T

    def column(self, name: str) -> np.ndarray:
        return self.columns[INDEX[name]]

    def __len__(self) -> int:
        return int(self.columns.shape[1])
