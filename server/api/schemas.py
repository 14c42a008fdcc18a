"""What the REST API accepts and returns, beyond the store's records, the engine's config
models, the trainer's session request (:mod:`sessions.requests`) and the machine service's
status (which it reuses as they are). Every request model forbids unknown fields, so a typo is
a 422 naming it rather than a silently ignored value."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Literal

from fastapi import Path
from pydantic import BaseModel, Field

from server.service import Live, MachineStatus
from server.service.users import UserIn, UserPatch
from sessions.codes import Role
from sessions.requests import MAX_ID, Finite, LimitsIn, Request, SessionStart
from sessions.store import (
    AccountRecord,
    EvaluationRecord,
    EventRecord,
    PhaseRecord,
    SessionRecord,
    SetpointRecord,
    UserRecord,
)

Id = Annotated[int, Path(ge=1, le=MAX_ID, description="id")]
MachineOut = MachineStatus


# -- auth ----------------------------------------------------------------------------------------
class LoginIn(Request):
    login: str = Field(..., min_length=1, max_length=64, examples=["coach"])
    password: str = Field(..., min_length=1, max_length=1024, examples=["correct horse battery"])


class TokenOut(BaseModel):
    access_token: str
    token_type: Literal["bearer"] = "bearer"
    expires_at: datetime


class Me(BaseModel):
    account: AccountRecord
    via: Literal["bearer", "cookie"]


# -- accounts -------------------------------------------------------------------------------------
class AccountIn(Request):
    login: str = Field(..., min_length=1, max_length=64, examples=["coach"])
    password: str = Field(..., min_length=8, max_length=1024)
    role: Role = "viewer"


class AccountPatch(Request):
    role: Role | None = None
    disabled: bool | None = None
    password: str | None = Field(None, min_length=8, max_length=1024)


# -- users ----------------------------------------------------------------------------------------
class SetpointIn(Request):
    velocity: Finite = Field(..., gt=0, le=100, description="rad/s", examples=[3.1])
    power: Finite | None = Field(None, description="W")


class Setpoints(BaseModel):
    current: SetpointRecord | None
    history: list[SetpointRecord]


# -- sessions -------------------------------------------------------------------------------------
class SessionOut(BaseModel):
    """A session (SI units): its summary, evaluations, events, protocol phases, live state."""

    session: SessionRecord
    evaluations: list[EvaluationRecord]
    events: list[EventRecord]
    phases: list[PhaseRecord] = []
    live: Live | None = None
    hint: str | None = Field(
        None, description="what the trainer should know: e.g. the best point at a bracket edge"
    )


class TelemetryOut(BaseModel):
    """Telemetry of a session: every channel as a list, full rate or decimated (min/max
    pairs per bucket), with units."""

    session_id: int
    samples: int
    decimated: bool
    units: dict[str, str]
    channels: dict[str, list[float | None]]


class Health(BaseModel):
    status: Literal["ok", "degraded"]
    machine: str
    worker: str
    database: str
    version: str


__all__ = [
    "MAX_ID",
    "AccountIn",
    "AccountPatch",
    "Finite",
    "Health",
    "LimitsIn",
    "Live",
    "LoginIn",
    "MachineOut",
    "Me",
    "SessionOut",
    "SessionStart",
    "SetpointIn",
    "Setpoints",
    "TelemetryOut",
    "TokenOut",
    "UserIn",
    "UserPatch",
    "UserRecord",
]
