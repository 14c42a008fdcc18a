"""What the REST API accepts and returns, beyond the store's records and the engine's config
models (which it reuses as they are). Every request model forbids unknown fields, so a typo is
a 422 naming it rather than a silently ignored value."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from fastapi import Path
from pydantic import BaseModel, ConfigDict, Field

from sessions.config import ControllerConfig, SeekerConfig, UserConfig
from sessions.store import (
    AccountRecord,
    EvaluationRecord,
    EventRecord,
    SessionRecord,
    SetpointRecord,
    UserRecord,
)

Finite = Annotated[float, Field(allow_inf_nan=False)]
MAX_ID = 2**53  # ids fit every database's integer (and JavaScript's)
Id = Annotated[int, Path(ge=1, le=MAX_ID, description="id")]


class Request(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


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
    role: Literal["admin", "trainer", "viewer"] = "viewer"


class AccountPatch(Request):
    role: Literal["admin", "trainer", "viewer"] | None = None
    disabled: bool | None = None
    password: str | None = Field(None, min_length=8, max_length=1024)


# -- users ----------------------------------------------------------------------------------------
class UserIn(Request):
    name: str = Field(..., min_length=1, max_length=200, examples=["Ada Lovelace"])
    notes: str = Field("", max_length=10_000)
    body_mass_kg: Finite | None = Field(None, gt=0, le=500, examples=[68.0])
    limb: str | None = Field(None, max_length=64, examples=["right arm"])
    sim_profile: UserConfig | None = Field(
        None, description="the simulated person standing in for this user on a simulated machine"
    )


class UserPatch(Request):
    name: str | None = Field(None, min_length=1, max_length=200)
    notes: str | None = Field(None, max_length=10_000)
    body_mass_kg: Finite | None = Field(None, gt=0, le=500)
    limb: str | None = Field(None, max_length=64)
    sim_profile: UserConfig | None = None


class SetpointIn(Request):
    velocity: Finite = Field(..., gt=0, le=100, description="rad/s", examples=[3.1])
    power: Finite | None = Field(None, description="W")


class Setpoints(BaseModel):
    current: SetpointRecord | None
    history: list[SetpointRecord]


# -- sessions -------------------------------------------------------------------------------------
class LimitsIn(Request):
    max_torque: Finite | None = Field(None, gt=0, description="N·m, at most the machine's")
    max_velocity: Finite | None = Field(None, gt=0, description="rad/s, at most the machine's")


START_EXAMPLE: dict[str, Any] = {
    "user_id": 1,
    "duration": 120.0,
    "controller": {"kind": "rise", "ks": 4.0, "beta": 0.5, "alpha_r": 4.0},
    "seeker": {"kind": "brent"},
    "limits": {"max_torque": 15.0},
}


class SessionStart(Request):
    """Start a session. Omitted parts take ergoseek's defaults; the seeker's bracket defaults
    to one around the user's stored optimum (or the engine's default without one)."""

    model_config = ConfigDict(json_schema_extra={"examples": [START_EXAMPLE]})

    user_id: int = Field(..., ge=1, le=MAX_ID)
    duration: Finite = Field(120.0, gt=0, le=3600.0, description="s")
    controller: ControllerConfig | None = None
    seeker: SeekerConfig | None = None
    limits: LimitsIn | None = None
    seed: int | None = Field(None, ge=0, description="simulated machine: the user's noise seed")


class Live(BaseModel):
    """A running session as the worker reports it now."""

    state: str
    t: float | None = None
    w: float | None = None
    wd: float | None = None
    u: float | None = None
    tau: float | None = None
    p: float | None = None
    W: float | None = None
    gamma: float | None = None
    phase: str | None = None
    target: float | None = None
    done: bool = False
    evaluations: int = 0


class SessionOut(BaseModel):
    session: SessionRecord
    evaluations: list[EvaluationRecord]
    events: list[EventRecord]
    live: Live | None = None


class TelemetryOut(BaseModel):
    """Telemetry of a session: every channel as a list, full rate or decimated (min/max
    pairs per bucket), with units."""

    session_id: int
    samples: int
    decimated: bool
    units: dict[str, str]
    channels: dict[str, list[float | None]]


# -- machine --------------------------------------------------------------------------------------
class MachineOut(BaseModel):
    backend: str
    state: str
    armed: bool
    fault: str | None
    session_id: int | None
    heartbeat_age_ms: float | None
    limits: dict[str, float]
    rate_hz: float
    timing: dict[str, Any] | None
    realtime: dict[str, Any] | None


class Health(BaseModel):
    status: Literal["ok", "degraded"]
    machine: str
    worker: str
    database: str
    version: str


__all__ = [
    "AccountIn",
    "AccountPatch",
    "Health",
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
