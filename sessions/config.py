"""Validated session configuration: the scenario a loop runs.

These pydantic models are the single description of a session. They are read from a TOML
scenario by ``ergoseek simulate``, sent by the REST API when a trainer starts a session, pickled
to the worker process and stored as JSON with the session. Every field has a unit and a
default; unknown keys are rejected so a typo never silently falls back to a default.
"""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from sessions import stability
from sessions.protocol.config import Protocol, headroom_problem

Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0, allow_inf_nan=False)]


SEED_LIMIT = 2**63  # seeds are 0 ≤ seed < 2^63: numpy's SeedSequence takes them, and every
# database's 64-bit integer holds them


class StrictModel(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class MachineConfig(StrictModel):
    """The machine (1) and its hard limits."""

    inertia: Positive = Field(0.1, description="J, kg·m² (the paper's testbed: 0.1)")
    max_torque: Positive = Field(20.0, description="|u| limit, N·m")
    max_velocity: Positive = Field(15.0, description="w limit, rad/s")
    passivity_c2: Positive = Field(
        50.0, description="c² of (5): the session stops if W(t) < -c², J"
    )


class UserConfig(StrictModel):
    """A simulated person: torque-velocity law plus real-world traits."""

    kind: Literal["hill", "linear"] = "hill"
    tau0: Positive = Field(3.0, description="isometric torque, N·m")
    wmax: Positive = Field(10.0, description="velocity at which torque reaches zero, rad/s")
    curvature: Positive = Field(0.25, description="Hill's a/F0 (hill only)")
    noise: NonNegative = Field(0.0, le=0.5, description="relative std of the torque fluctuation")
    noise_bandwidth: Positive = Field(5.0, le=200.0, description="noise corner frequency, Hz")
    ripple: NonNegative = Field(0.0, lt=1.0, description="stroke-angle ripple r: τ·(1 + r sin q)")
    fatigue_tau: NonNegative = Field(0.0, description="τ0(t) = τ0·exp(-t/fatigue_tau), s; 0 = none")
    fatigue_model: Literal["exponential", "three-compartment"] = Field(
        "exponential", description="three-compartment: Xia & Frey Law (2008), ignores fatigue_tau"
    )
    fatigue_effort: Positive = Field(
        0.5, le=1.0, description="three-compartment target load, fraction of capacity"
    )
    fatigue_f: Positive = Field(0.01, description="three-compartment fatigue rate F, 1/s")
    fatigue_r: Positive = Field(0.002, description="three-compartment recovery rate R, 1/s")


class ControllerConfig(StrictModel):
    """Controller A, eq. (7) ("measured"), or controller B, eq. (23) ("rise").

    Their upper bounds depend on the loop rate and the inertia, so SessionConfig checks them
    (sessions/stability.py): k·dt/J ≤ 1; (ks + 1)·dt/J ≤ 2/(2 − αr·dt); αr·dt ≤ ½; β's
    sign-integral ripple within 1/20 of the torque limit."""

    kind: Literal["rise", "measured"] = "rise"
    ks: Positive = Field(4.0, description="RISE gain ks (23); (ks + 1)·dt/J ≤ 2/(2 − αr·dt)")
    beta: Positive = Field(0.5, description="RISE β1 + β2 (23), N·m/s; ripple ≤ 1/20 torque limit")
    alpha_r: Positive = Field(4.0, description="RISE αr (15), 1/s; αr·dt ≤ 1/2")
    k: Positive = Field(1.0, description="measured-torque gain k (7), N·m·s/rad; k·dt/J ≤ 1")


class FilterConfig(StrictModel):
    """Trajectory filter: p^n / (s + p)^n, n = 4 is (32) with p = 3, n = 3 is (33)."""

    order: Literal[3, 4] = 4
    pole: Positive = Field(3.0, le=200.0, description="repeated real pole p, rad/s")


class SeekerConfig(StrictModel):
    """Desired-trajectory generator: which extremum seeker and its parameters."""

    kind: Literal["parabolic", "brent", "perturbation", "fixed"] = "brent"
    bracket: tuple[Positive, Positive, Positive] = Field(
        (1.0, 3.5, 6.0), description="γ1 < γ2 < γ3: lower bound, best guess, upper bound, rad/s"
    )
    rho: Positive = Field(1.0, le=5.0, description="ρ of the modified power p = τ·w^ρ (4)")
    objective: Literal["power", "surrogate"] = Field(
        "power", description="power: τ (or τ̂)·wd^ρ; surrogate: eq. (31), the paper's Exp. 1"
    )
    filter: FilterConfig = FilterConfig()
    start_delay: NonNegative = Field(1.5, description="no measurement before this time, s")
    e1: Positive = Field(0.1, description="ē1: measure only when |e| ≤ ē1, rad/s")
    e2: Positive = Field(0.05, description="ē2: measure only when |wd - γ| ≤ ē2, rad/s")
    window: Positive = Field(0.5, description="shortest averaging window per candidate, s")
    max_window: Positive = Field(6.0, description="longest averaging window per candidate, s")
    quiet: Positive = Field(
        0.01, description="relative std of p under which the shortest window is enough"
    )
    threshold: Positive = Field(0.1, description="stop when the bracket is narrower, rad/s")
    min_step: Positive = Field(0.05, description="no two candidates closer than this, rad/s")
    step: Positive | None = Field(
        None, description="brent: first probe's distance from γ2 (default: a tenth of the bracket)"
    )
    noise_k: NonNegative = Field(
        2.0, description="brent: points whose power differs by < k·σ are not told apart"
    )
    max_evaluations: int = Field(30, ge=3, le=1000)
    # perturbation, eq. (14)
    amplitude: Positive = Field(0.2, description="ae: dither amplitude, rad/s")
    omega: Positive = Field(1.5, description="ω: dither frequency, rad/s")
    alpha0: Positive = Field(0.5, description="α0: gradient filter rate, 1/s")
    alpha_f: NonNegative = Field(0.0, description="αf: leak on θ, 1/s (0 = Krstić & Deng)")
    kf1: Positive = Field(8.0, description="kf1: adaptation gain")
    kf2: Positive = Field(0.5, description="kf2: power high-pass rate, 1/s")
    saturation: Positive = Field(100.0, description="sat(p) = P·tanh(p/P), W")
    # fixed
    setpoint: Positive | None = Field(None, description="fixed: velocity to hold (default γ2)")

    @field_validator("bracket")
    @classmethod
    def _increasing(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        if not v[0] < v[1] < v[2]:
            raise ValueError(f"must satisfy γ1 < γ2 < γ3, got {list(v)}")
        return v

    @model_validator(mode="after")
    def _windows(self) -> SeekerConfig:
        if self.max_window < self.window:
            raise ValueError("max_window: must be at least window")
        return self


class SessionConfig(StrictModel):
    """One whole session: how long, how fast, on what machine, for whom, with what."""

    duration: Positive = Field(
        120.0,
        le=24 * 3600,
        description="s; with a protocol, the longest it may take (default: the protocol's own)",
    )
    rate: Positive = Field(1000.0, ge=50.0, le=20000.0, description="loop rate, Hz")
    seed: int = Field(
        1, ge=0, lt=SEED_LIMIT, description="seeds every random process of the simulated user"
    )
    machine: MachineConfig = MachineConfig()
    user: UserConfig = UserConfig()
    controller: ControllerConfig = ControllerConfig()
    seeker: SeekerConfig = SeekerConfig()
    protocol: Protocol | None = Field(
        None, description="the phases the session runs (none: one seek phase for the duration)"
    )

    @model_validator(mode="after")
    def _within_machine(self) -> SessionConfig:
        top = self.seeker.bracket[2]
        if top >= self.machine.max_velocity:
            raise ValueError(
                f"seeker.bracket: γ3 = {top} must be below machine.max_velocity "
                f"= {self.machine.max_velocity}"
            )
        if self.seeker.setpoint is not None and self.seeker.setpoint >= self.machine.max_velocity:
            raise ValueError("seeker.setpoint: must be below machine.max_velocity")
        if self.seeker.kind == "perturbation" and top + self.seeker.amplitude >= (
            self.machine.max_velocity
        ):  # θ is projected onto the bracket; the dither rides on it
            raise ValueError(
                f"seeker.amplitude: γ3 + ae = {top + self.seeker.amplitude:g} must be below "
                f"machine.max_velocity = {self.machine.max_velocity}"
            )
        return self

    @model_validator(mode="after")
    def _holdable(self) -> SessionConfig:
        """Gains and a reference the discrete loop can hold at this rate and inertia: the
        bounds of :mod:`sessions.stability`, checked for every entry point (TOML, REST, UI)."""
        problem = stability.violation(self)
        if problem is not None:
            raise ValueError(problem)
        return self

    @model_validator(mode="after")
    def _protocol(self) -> SessionConfig:
        """A protocol's velocities within the machine's headroom and never above the bracket's
        upper bound γ3 (a hard bound for this person, as for the seeker), and a duration that
        lets it finish (by default exactly that)."""
        if self.protocol is None:
            return self
        problem = headroom_problem(self.protocol, self.machine.max_velocity)
        if problem is not None:
            raise ValueError(f"{problem[0]}: {problem[1]}")
        top = self.seeker.bracket[2]
        for key, v in self.protocol.velocities():
            if v > top:
                raise ValueError(
                    f"{key}: {v:g} rad/s is above the bracket's upper bound γ3 = {top:g} rad/s "
                    "(the person's limit: widen seeker.bracket if it is safe)"
                )
        bracket = (self.seeker.bracket[0], self.seeker.bracket[2])
        longest = self.protocol.longest(bracket, self.machine.max_velocity)
        if "duration" not in self.model_fields_set:
            if longest > 24 * 3600:
                raise ValueError(f"protocol: takes up to {longest:.0f} s, more than a day")
            object.__setattr__(self, "duration", float(math.ceil(longest)))  # frozen: set once
            return self
        if self.duration < longest:
            raise ValueError(
                f"duration: {self.duration:g} s is shorter than the protocol may take "
                f"({math.ceil(longest)} s); leave it out to use that"
            )
        return self

    @property
    def dt(self) -> float:
        return 1.0 / self.rate


_KEY = re.compile(r"[a-z_][a-z0-9_]*(\.[a-z0-9_]+)*")  # seeker.bracket, phases.2


class ScenarioError(ValueError):
    """A scenario that cannot be used, with a one-line reason naming the key."""


def validation_problems(exc: ValidationError) -> list[tuple[str, str]]:
    """``(key.path, reason)`` per problem (a model-level check names its key in its message,
    ``"seeker.bracket: …"``; it is taken from there)."""
    parts = []
    for err in exc.errors():
        path = [str(x) for x in err["loc"]]
        msg = err["msg"].removeprefix("Value error, ")
        # a model-level check names its key itself: "seeker.bracket: …" or "max_window: …"
        key, sep, rest = msg.partition(": ")
        if sep and _KEY.fullmatch(key):
            inner = key.split(".")
            path = inner if path and path[-1:] == inner[:1] else [*path, *inner]
            msg = rest
        loc = ".".join(path) or "scenario"
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        elif err["type"] != "value_error" and "input" in err and not isinstance(err["input"], dict):
            msg = f"{msg} (got {err['input']!r})"
        parts.append((loc, msg))
    return parts


def describe_validation_error(exc: ValidationError) -> str:
    """One line for every problem: ``key.path: reason; …``."""
    return "; ".join(f"{key}: {reason}" for key, reason in validation_problems(exc))


def parse_session_config(data: dict[str, Any]) -> SessionConfig:
    try:
        return SessionConfig.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(describe_validation_error(exc)) from None


def load_scenario(path: str | Path) -> SessionConfig:
    """Read and validate a TOML scenario; raise ScenarioError with a one-line reason."""
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ScenarioError(f"{p}: no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{p}: not valid TOML ({exc})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"{p}: cannot read ({exc})") from None
    return parse_session_config(data)
