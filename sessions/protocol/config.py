"""A session protocol as validated configuration: the phases a session runs, in order.

    warmup  → a fixed velocity, or a gentle ramp to it, for N s (an easy effort);
    seek    → the extremum seeker, as a session without a protocol runs it;
    train   → work/rest intervals at the optimum found (tracking it where the seeker can),
              each work interval led by a countdown; rest at a slow velocity or at rest;
    profile → a velocity-spectrum test: isokinetic steps across the bracket (sessions/profile.py);
    cooldown→ a ramp down to rest, then the person relaxes and the torque is released.

A protocol is plain data: stored as a template (JSON), sent in a REST request, carried inside
the :class:`~sessions.config.SessionConfig` to the worker. Velocities are rad/s and times s
(the REST API is SI; the dashboard converts). Where a velocity is left out it is taken from the
session when the phase begins (the bracket, the optimum found): see each field. Every session
ends with a controlled stop at rest: a protocol whose last phase is not a cool-down gets the
runner's own stop (docs/protocols.md).

Efforts (0 … 1) are the cues the person is given: what a trainer asks for ("easy", "full",
"relax"); the dashboard shows them and a simulated person follows them
(:mod:`sessions.protocol.cues`). They never change what the machine does.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from sessions.codes import PHASE_KINDS

Order = Literal["ascending", "descending", "interleaved", "random"]  # sessions.profile.ORDERS

MAX_PHASE = 4 * 3600.0  # s: the longest any one phase may last
MAX_PHASES = 50
STOP_DECELERATION = 2.0  # rad/s²: the runner's own stop brings γ down at this rate
REST_HOLD = 0.5  # s the handle must stay at rest before the torque is released
REST_VELOCITY = 0.05  # rad/s: |w| under this counts as at rest
REST_GRACE = 5.0  # s: the hold at rest ends after this even if the handle still moves

Seconds = Annotated[float, Field(gt=0, le=MAX_PHASE, allow_inf_nan=False)]
Pause = Annotated[float, Field(ge=0, le=MAX_PHASE, allow_inf_nan=False)]
Velocity = Annotated[float, Field(gt=0, le=100.0, allow_inf_nan=False)]
Effort = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]
Label = Annotated[str, Field(max_length=60)]

STOP = PHASE_KINDS[-1]  # "stop": the runner's own closing phase (not configurable)


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Warmup(_Model):
    kind: Literal["warmup"] = "warmup"
    name: Label = ""
    duration: Seconds = Field(120.0, description="s")
    velocity: Velocity | None = Field(
        None, description="rad/s to hold (default: the bracket's lower bound γ1)"
    )
    ramp: Pause = Field(
        0.0,
        description="s over which the velocity rises linearly from where the handle is "
        "(0: the trajectory filter's own smooth step); at most the duration",
    )
    effort: Effort = Field(0.5, description="the effort asked of the person, 0 … 1")

    @model_validator(mode="after")
    def _ramp(self) -> Warmup:
        if self.ramp > self.duration:
            raise ValueError(
                f"ramp: {self.ramp:g} s is longer than the phase ({self.duration:g} s)"
            )
        return self


class Seek(_Model):
    kind: Literal["seek"] = "seek"
    name: Label = ""
    duration: Seconds = Field(180.0, description="s: the longest the search may take")
    until_converged: bool = Field(
        True, description="end the phase once the seeker has converged (and held `hold` s)"
    )
    hold: Pause = Field(5.0, description="s held at the optimum after convergence")


class Train(_Model):
    kind: Literal["train"] = "train"
    name: Label = ""
    intervals: int = Field(6, ge=1, le=200)
    work: Seconds = Field(20.0, description="s of work per interval")
    rest: Pause = Field(40.0, description="s of rest after each work interval")
    velocity: Velocity | None = Field(
        None,
        description="rad/s of the work intervals (default: the optimum the seek phase found, "
        "else the bracket's best guess γ2, which is the user's stored optimum)",
    )
    track: bool = Field(
        True, description="follow the optimum during work where the seeker can (its track phase)"
    )
    rest_velocity: Annotated[float, Field(ge=0, le=100.0, allow_inf_nan=False)] = Field(
        1.0, description="rad/s during rest; 0 brings the handle to a controlled stop"
    )
    rest_effort: Effort = Field(0.0, description="the effort asked during rest (0: relax)")
    countdown: Annotated[float, Field(ge=0, le=30.0, allow_inf_nan=False)] = Field(
        3.0,
        description="s before each work interval, during which the handle is brought up to "
        "the work velocity: the first interval's leads the phase, the others' are the end of "
        "the rest before them",
    )

    @model_validator(mode="after")
    def _countdown(self) -> Train:
        if self.intervals > 1 and self.countdown > self.rest:
            raise ValueError(
                f"countdown: {self.countdown:g} s is longer than the rest ({self.rest:g} s) it ends"
            )
        return self

    @property
    def planned(self) -> float:
        return self.countdown + self.intervals * (self.work + self.rest)


class Profile(_Model):
    kind: Literal["profile"] = "profile"
    name: Label = ""
    count: int = Field(8, ge=3, le=50, description="K: velocities tested")
    hold: Annotated[float, Field(gt=0, le=600.0, allow_inf_nan=False)] = Field(
        8.0, description="s per step (lengthened to settle and cover whole turns)"
    )
    order: Order = Field("interleaved", description="ascending, descending, interleaved, random")
    seed: int = Field(0, ge=0, le=2**31 - 1, description="for order = random")
    velocities: tuple[Velocity, Velocity] | None = Field(
        None, description="[lo, hi] rad/s (default: the bracket γ1 … γ3)"
    )
    model: Literal["auto", "hill", "linear"] = Field("auto", description="the law fitted")
    effort: Effort = Field(1.0, description="the effort asked: a test is done at full effort")

    @model_validator(mode="after")
    def _span(self) -> Profile:
        if self.velocities is not None and not self.velocities[0] < self.velocities[1]:
            raise ValueError(
                f"velocities: must be increasing [lo, hi], got {list(self.velocities)}"
            )
        if self.model == "hill" and self.count < 4:
            raise ValueError("count: Hill's law needs at least 4 steps")
        return self

    def span(self, bracket: tuple[float, float]) -> tuple[float, float]:
        return self.velocities if self.velocities is not None else bracket

    def longest(self, bracket: tuple[float, float], max_velocity: float) -> float:
        """s the test can take from any starting velocity (the first step's settling varies)."""
        from sessions.profile import plan_profile  # (it imports sessions.config, which imports us)

        span = self.span(bracket)
        return max(
            plan_profile(span, self.count, self.hold, order=self.order, seed=self.seed,
                         start_velocity=v).duration
            for v in (0.0, max_velocity)
        )  # fmt: skip


class Cooldown(_Model):
    kind: Literal["cooldown"] = "cooldown"
    name: Label = ""
    duration: Seconds = Field(60.0, description="s of the ramp from the current velocity to rest")
    effort: Effort = Field(0.3, description="the effort asked at its start; it falls to 0")
    hold: Annotated[float, Field(ge=0, le=60.0, allow_inf_nan=False)] = Field(
        3.0, description="s at rest, relaxed, before the torque is released"
    )


PhaseConfig = Annotated[Warmup | Seek | Train | Profile | Cooldown, Field(discriminator="kind")]


class Protocol(_Model):
    """The phases of a session, in order (at most one seek; a cool-down only last)."""

    name: Annotated[str, Field(max_length=100)] = ""
    phases: tuple[PhaseConfig, ...] = Field(..., min_length=1, max_length=MAX_PHASES)

    @model_validator(mode="after")
    def _order(self) -> Protocol:
        seeks = [i for i, ph in enumerate(self.phases) if ph.kind == "seek"]
        if len(seeks) > 1:
            raise ValueError(f"phases.{seeks[1]}: at most one seek phase (found {len(seeks)})")
        for i, ph in enumerate(self.phases[:-1]):
            if ph.kind == "cooldown":
                raise ValueError(f"phases.{i}: a cool-down ends the protocol: it must be last")
        return self

    @property
    def ends_at_rest(self) -> bool:
        return self.phases[-1].kind == "cooldown"

    def velocities(self) -> list[tuple[str, float]]:
        """Every velocity the protocol names, with its key (for the machine's bounds)."""
        out: list[tuple[str, float]] = []
        for i, ph in enumerate(self.phases):
            for key in ("velocity", "rest_velocity"):
                v = getattr(ph, key, None)
                if isinstance(v, float):
                    out.append((f"protocol.phases.{i}.{key}", v))
            if isinstance(ph, Profile) and ph.velocities is not None:
                out.append((f"protocol.phases.{i}.velocities", ph.velocities[1]))
        return out

    def longest(self, bracket: tuple[float, float], max_velocity: float) -> float:
        """The longest the protocol can take, its closing stop included, s: what the session's
        duration must allow."""
        total = 0.0
        for ph in self.phases:
            total += phase_longest(ph, bracket, max_velocity)
        if not self.ends_at_rest:
            total += max_velocity / STOP_DECELERATION + REST_HOLD + REST_GRACE
        return total


def phase_longest(ph: Any, bracket: tuple[float, float], max_velocity: float) -> float:
    """The longest one phase can take, s."""
    if isinstance(ph, Train):
        return ph.planned
    if isinstance(ph, Profile):
        return ph.longest(bracket, max_velocity)
    if isinstance(ph, Cooldown):
        return ph.duration + max(ph.hold, REST_HOLD) + REST_GRACE
    return float(ph.duration)


def phase_label(ph: Any, index: int) -> str:
    """What a phase is called: its name, else its kind and position (``train 3``)."""
    return ph.name or f"{ph.kind} {index + 1}"


def headroom_problem(protocol: Protocol, max_velocity: float) -> tuple[str, str] | None:
    """(key, reason) for a velocity at or above 95 % of the machine's limit, else None."""
    top = 0.95 * max_velocity
    for key, v in protocol.velocities():
        if v >= top:
            return key, f"{v:g} rad/s must be below 95 % of machine.max_velocity ({top:g} rad/s)"
    return None


def describe(protocol: Protocol) -> str:
    """One line: ``warmup 60 s → seek ≤ 180 s → train 6 × 20/40 s → cooldown 60 s``."""
    parts = []
    for ph in protocol.phases:
        if isinstance(ph, Train):
            parts.append(f"train {ph.intervals} × {ph.work:g}/{ph.rest:g} s")
        elif isinstance(ph, Seek):
            parts.append(f"seek ≤ {ph.duration:g} s")
        elif isinstance(ph, Profile):
            parts.append(f"profile {ph.count} × {ph.hold:g} s")
        else:
            parts.append(f"{ph.kind} {ph.duration:g} s")
    return " → ".join(parts)
