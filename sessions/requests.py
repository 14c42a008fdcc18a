"""A trainer's request for a session, and the policy that turns it into a :class:`SessionConfig`
for the machine at hand. The REST API and the dashboard send the same request
(:class:`SessionStart`) and get the same session from it.

The policy, in the order it applies:

- **limits**: a request may lower the machine's torque and velocity limits, never raise them;
- **bracket**: unless the request gives one, ``[0.6 v, v, 1.5 v]`` around the user's stored
  optimum v, kept within :data:`HEADROOM` of the velocity limit; without a stored optimum, the
  engine's default bracket, scaled down into a machine too slow for it;
- **setpoint** of the ``fixed`` seeker: unless given, the stored optimum (within the headroom);
- **controller**: one the machine can run (controller A needs a torque sensor);
- **user**: the simulated person standing in for the user on a simulated machine;
- **seed**: the request's, or one drawn from the clock;
- **protocol**: the request's (a template's, resolved by the caller into ``protocol``); its
  velocities within the bracket; the duration, unless given, the longest the protocol takes.

Problems raise :class:`RequestError` naming the field (dotted, under the request) and the
reason; nothing is started.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from sessions.config import (
    SEED_LIMIT,
    ControllerConfig,
    MachineConfig,
    SeekerConfig,
    SessionConfig,
    UserConfig,
    validation_problems,
)
from sessions.machine.spec import check_controller
from sessions.protocol.config import Protocol

Finite = Annotated[float, Field(allow_inf_nan=False)]
MAX_ID = 2**53  # ids fit every database's integer (and JavaScript's)

HEADROOM = 0.9  # brackets and setpoints the policy picks stay below this fraction of w_max
AROUND = (0.6, 1.0, 1.5)  # the bracket around a stored optimum v: [0.6 v, v, 1.5 v]
MIDDLE_MAX = 0.8  # of the headroom: room above the middle of a bracket around an optimum
LOWEST = 0.2  # rad/s: the lowest γ1 of a bracket around an optimum


class Request(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class LimitsIn(Request):
    max_torque: Finite | None = Field(None, gt=0, description="N·m, at most the machine's")
    max_velocity: Finite | None = Field(None, gt=0, description="rad/s, at most the machine's")


START_EXAMPLE: dict[str, Any] = {
    "user_id": 1,
    "duration": 120.0,
    "controller": {"kind": "rise", "beta": 0.5, "alpha_r": 4.0},
    "seeker": {"kind": "brent"},
    "limits": {"max_torque": 15.0},
}


class SessionStart(Request):
    """Start a session. Omitted parts take ergoseek's defaults; the seeker's bracket defaults
    to one around the user's stored optimum (or the engine's default without one)."""

    model_config = ConfigDict(json_schema_extra={"examples": [START_EXAMPLE]})

    user_id: int = Field(..., ge=1, le=MAX_ID)
    duration: Finite = Field(
        120.0,
        gt=0,
        le=3600.0,
        description="s; with a protocol, leave it out: the longest the protocol may take",
    )
    controller: ControllerConfig | None = None
    seeker: SeekerConfig | None = None
    limits: LimitsIn | None = None
    seed: int | None = Field(
        None, ge=0, lt=SEED_LIMIT, description="simulated machine: the user's noise seed"
    )
    protocol: Protocol | None = Field(
        None, description="the phases to run (SI: rad/s, s); none: one seek phase"
    )
    template_id: int | None = Field(
        None, ge=1, le=MAX_ID, description="run this protocol template (instead of `protocol`)"
    )

    @model_validator(mode="after")
    def _one_protocol(self) -> SessionStart:
        if self.protocol is not None and self.template_id is not None:
            raise ValueError("template_id: give a template or a protocol, not both")
        return self


class RequestError(ValueError):
    """A request the machine cannot take: ``field`` (dotted, under the request) and ``reason``."""

    def __init__(self, field: str, reason: str) -> None:
        self.field = field
        self.reason = reason
        super().__init__(f"{field}: {reason}")


@dataclass(frozen=True)
class Rig:
    """The machine a request is fitted to: its name, its physics and hard limits, the loop
    rate it runs at, and whether it measures the user's torque."""

    name: str
    machine: MachineConfig
    rate: float
    has_torque_sensor: bool


def bracket_around(optimum: float | None, max_velocity: float) -> tuple[float, float, float] | None:
    """``[0.6 v, v, 1.5 v]`` around a stored optimum v, within the machine's range (None when
    there is no optimum, or no room for a bracket around it)."""
    if optimum is None or not math.isfinite(optimum) or optimum <= 0:
        return None
    top = HEADROOM * max_velocity
    mid = min(optimum, MIDDLE_MAX * top)
    lo, hi = max(LOWEST, AROUND[0] * mid), min(AROUND[2] * mid, top)
    return (lo, mid, hi) if lo < mid < hi else None


def auto_bracket(
    optimum: float | None, max_velocity: float, default: tuple[float, float, float] | None = None
) -> tuple[tuple[float, float, float], bool]:
    """The bracket a request without one gets, and whether it is around the stored optimum
    (else: ``default``, the engine's unless given, scaled into a slow machine)."""
    around = bracket_around(optimum, max_velocity)
    if around is not None:
        return around, True
    lo, mid, hi = default or SeekerConfig().bracket
    top = HEADROOM * max_velocity
    if hi >= top:
        k = top / hi
        return (lo * k, mid * k, hi * k), False
    return (lo, mid, hi), False


def fit_limits(limits: LimitsIn | None, machine: MachineConfig) -> MachineConfig:
    """The machine with the request's lower limits (never higher ones)."""
    if limits is None:
        return machine
    lower: dict[str, float] = {}
    for name, unit in (("max_torque", "N·m"), ("max_velocity", "rad/s")):
        asked = getattr(limits, name)
        if asked is None:
            continue
        top = getattr(machine, name)
        if asked > top:
            raise RequestError(f"limits.{name}", f"must not exceed the machine's {top:g} {unit}")
        lower[name] = asked
    return machine.model_copy(update=lower)


def fit_seeker(
    seeker: SeekerConfig | None, optimum: float | None, max_velocity: float
) -> SeekerConfig:
    """The request's seeker with what it left out chosen around the stored optimum."""
    given = seeker.model_fields_set if seeker is not None else set()
    seeker = seeker or SeekerConfig()
    chosen: dict[str, Any] = {}
    if "bracket" not in given:
        chosen["bracket"], _ = auto_bracket(optimum, max_velocity, seeker.bracket)
    if "setpoint" not in given and seeker.kind == "fixed" and optimum is not None:
        chosen["setpoint"] = min(optimum, HEADROOM * max_velocity)
    # (chosen values are valid by construction; the session's checks below still run)
    return seeker.model_copy(update=chosen)


def session_config(
    req: SessionStart,
    rig: Rig,
    *,
    sim_profile: dict[str, Any] | None = None,
    optimum: float | None = None,
) -> SessionConfig:
    """The session ``req`` asks for on ``rig``, for a user with this stored simulated
    profile and optimum. Raises :class:`RequestError`."""
    if req.template_id is not None:  # the caller resolves it (server.service.templates)
        raise RequestError("template_id", "not resolved into a protocol: nothing started")
    machine = fit_limits(req.limits, rig.machine)
    user = UserConfig.model_validate(sim_profile) if sim_profile else UserConfig()
    seed = req.seed if req.seed is not None else int(time.time() * 1000) % 2**31
    parts: dict[str, Any] = {}
    if req.protocol is None or "duration" in req.model_fields_set:
        parts["duration"] = req.duration
    if req.protocol is not None:
        parts["protocol"] = req.protocol
    try:
        cfg = SessionConfig(
            rate=rig.rate,
            seed=seed,
            machine=machine,
            user=user,
            controller=req.controller or ControllerConfig(),
            seeker=fit_seeker(req.seeker, optimum, machine.max_velocity),
            **parts,
        )
    except ValidationError as exc:
        field, reason = validation_problems(exc)[0]
        raise RequestError(field, reason) from None
    try:
        check_controller(rig.name, rig.has_torque_sensor, cfg.controller.kind)
    except ValueError as exc:
        raise RequestError("controller.kind", str(exc)) from None
    return cfg
