"""What the trainer's-workflow routes accept and return: protocol templates, previews,
preferences, progress, overlays. The API is SI throughout (rad/s, N·m, W, J, s); W/kg where the
user's body mass is known. Request models forbid unknown fields (a typo is a 422 naming it)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from sessions.config import SeekerConfig
from sessions.protocol.config import Protocol
from sessions.requests import Request
from sessions.store import ProgressPoint
from sessions.units import VelocityUnit

SI = "SI units: velocities rad/s, torques N·m, powers W, work J, times s"

TEMPLATE_EXAMPLE: dict[str, Any] = {
    "name": "Intervals 6 × 20/40",
    "description": "warm-up, find the optimum, six intervals, cool-down",
    "shared": True,
    "protocol": {
        "name": "Intervals 6 × 20/40",
        "phases": [
            {"kind": "warmup", "duration": 120, "effort": 0.5},
            {"kind": "seek", "duration": 180},
            {"kind": "train", "intervals": 6, "work": 20, "rest": 40},
            {"kind": "cooldown", "duration": 60},
        ],
    },
}


class TemplateIn(Request):
    """A new protocol template (the protocol in SI units: rad/s, s)."""

    model_config = ConfigDict(
        extra="forbid", allow_inf_nan=False, json_schema_extra={"examples": [TEMPLATE_EXAMPLE]}
    )

    name: str = Field(..., min_length=1, max_length=100)
    description: str = Field("", max_length=2000)
    shared: bool = Field(False, description="visible to (and editable by) every trainer")
    protocol: Protocol


class TemplatePatch(Request):
    name: str | None = Field(None, min_length=1, max_length=100)
    description: str | None = Field(None, max_length=2000)
    shared: bool | None = None
    protocol: Protocol | None = None


class PreviewIn(Request):
    """A protocol to check against a user's session (the bracket the session would get)."""

    protocol: Protocol
    user_id: int | None = Field(None, ge=1, le=2**53)
    seeker: SeekerConfig | None = Field(None, description="as in a session start")


class PhasePreview(BaseModel):
    index: int
    kind: str
    name: str
    longest: float = Field(..., description="s, the longest this phase can take")


class PreviewOut(BaseModel):
    summary: str
    duration: float = Field(..., description="s: the session's duration (the longest it takes)")
    bracket: tuple[float, float, float] = Field(..., description="γ1, γ2, γ3 rad/s")
    phases: list[PhasePreview]


class Preferences(BaseModel):
    velocity_unit: VelocityUnit = Field(
        "rpm", description="how the dashboard shows velocities; the REST API stays in rad/s"
    )


class PreferencesIn(Request):
    velocity_unit: VelocityUnit


class ProgressSession(ProgressPoint):
    """One session on the progress chart (SI units), with W/kg where the body mass is known."""

    peak_power_per_kg: float | None = None
    mean_power_per_kg: float | None = None
    optimum_p_per_kg: float | None = None


class ProgressOut(BaseModel):
    """A user's sessions, oldest first: optimum found and at the end, powers, profiles."""

    user_id: int
    body_mass_kg: float | None
    units: str = SI
    sessions: list[ProgressSession]


class OverlaySession(BaseModel):
    session_id: int
    offset: float = Field(..., description="s: session time at the alignment point")
    samples: int
    channels: dict[str, list[float | None]]


class OverlayOut(BaseModel):
    """Two sessions on one time axis (s from the alignment point), as bucket means."""

    align: str
    t: list[float]
    units: dict[str, str]
    sessions: list[OverlaySession]


ExportFormat = Literal["pdf", "fit"]
