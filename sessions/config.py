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


# Physical bounds of a simulated person (issue 13): every field is bounded by what a human can
# do, so that no profile can feed the loop absurd or non-finite numbers. The strongest measured
# human joint torques (elite knee extension, sprint cyclists' crank torque) stay below about
# 400 N·m; the fastest limb velocities at a handle or crank (sprint cadence ≈ 250 rpm ≈ 26 rad/s)
# below 50 rad/s. The machine's own torque limit (machine.max_torque) is not a bound on the
# person: a user stronger than the motor is real, and the machine's limits handle them.
PERSON_MAX_TORQUE = 500.0  # N·m
PERSON_MAX_VELOCITY = 50.0  # rad/s
LONGEST_TIME = 1e6  # s, about 11.6 days: longer time constants mean "none" in practice


def _none_or_at_least_a_second(v: float) -> float:
    if 0.0 < v < 1.0:
        raise ValueError(f"must be 0 (none) or at least 1 s, got {v}")
    return v


class UserConfig(StrictModel):
    """A simulated person: torque-velocity law plus real-world traits, within human bounds.

    The torque at time t is τ(w, t) = τ0(t)·g(w / s(t))·(1 + n(t))·(1 + r sin q), clamped to
    [0, τmax]: τ0(t) falls with (torque) fatigue, s(t) shrinks the velocity axis (velocity
    fatigue), n is the noise and r the stroke ripple. ``kind = "table"`` gives τ(w) as measured
    points instead of a law (tau0, wmax and curvature are then not used)."""

    kind: Literal["hill", "linear", "table"] = "hill"
    tau0: Positive = Field(
        3.0,
        le=PERSON_MAX_TORQUE,
        description="isometric torque, N·m (≤ 500: beyond any person's joint torque)",
    )
    wmax: Positive = Field(
        10.0,
        ge=0.1,
        le=PERSON_MAX_VELOCITY,
        description="velocity at which torque reaches zero, rad/s (0.1-50: a person's range)",
    )
    curvature: Positive = Field(
        0.25,
        ge=0.02,
        le=10.0,
        description="Hill's a/F0 (hill only); muscle measures 0.1-0.6, 10 is nearly linear",
    )
    points: tuple[tuple[float, float], ...] | None = Field(
        None,
        description="table only: [[w, τ], …] in rad/s and N·m, w increasing from ≥ 0, τ ≥ 0; "
        "interpolated by PCHIP (monotone), τ = 0 past the last point",
    )
    noise: NonNegative = Field(0.0, le=0.5, description="relative std of the torque fluctuation")
    noise_bandwidth: Positive = Field(
        5.0, ge=0.01, le=200.0, description="noise corner frequency, Hz"
    )
    ripple: NonNegative = Field(0.0, lt=1.0, description="stroke-angle ripple r: τ·(1 + r sin q)")
    fatigue_tau: NonNegative = Field(
        0.0,
        le=LONGEST_TIME,
        description="τ0(t) = τ0·exp(-t/fatigue_tau), s; 0 = none, else ≥ 1 s",
    )
    fatigue_model: Literal["exponential", "three-compartment"] = Field(
        "exponential", description="three-compartment: Xia & Frey Law (2008), ignores fatigue_tau"
    )
    fatigue_effort: Positive = Field(
        0.5, le=1.0, description="three-compartment target load, fraction of capacity"
    )
    fatigue_f: Positive = Field(
        0.01, le=1.0, description="three-compartment fatigue rate F, 1/s (muscles: 0.001-0.1)"
    )
    fatigue_r: Positive = Field(
        0.002, le=1.0, description="three-compartment recovery rate R, 1/s (muscles: 0.0005-0.05)"
    )
    velocity_fatigue_tau: NonNegative = Field(
        0.0,
        le=LONGEST_TIME,
        description="T of the velocity axis' shrinking s(t) = f + (1 - f)·exp(-t/T), s; "
        "0 = none, else ≥ 1 s. w*(t) = s(t)·w*(0)",
    )
    velocity_fatigue_floor: Positive = Field(
        0.8, le=1.0, description="f: what s(t) shrinks to, 0 < f ≤ 1"
    )

    @field_validator("fatigue_tau", "velocity_fatigue_tau")
    @classmethod
    def _seconds(cls, v: float) -> float:
        return _none_or_at_least_a_second(v)

    @field_validator("points")
    @classmethod
    def _table(
        cls, v: tuple[tuple[float, float], ...] | None
    ) -> tuple[tuple[float, float], ...] | None:
        if v is None:
            return v
        if len(v) < 3:
            raise ValueError(f"needs at least 3 points [w, τ], got {len(v)}")
        if len(v) > 1000:
            raise ValueError(f"at most 1000 points, got {len(v)}")
        for i, (w, tau) in enumerate(v):
            if not (math.isfinite(w) and math.isfinite(tau)):
                raise ValueError(f"point {i}: must be finite numbers, got {[w, tau]}")
            if not 0.0 <= w <= PERSON_MAX_VELOCITY:
                raise ValueError(f"point {i}: w = {w} must be within [0, {PERSON_MAX_VELOCITY}]")
            if not 0.0 <= tau <= PERSON_MAX_TORQUE:
                raise ValueError(f"point {i}: τ = {tau} must be within [0, {PERSON_MAX_TORQUE}]")
            if i and not w > v[i - 1][0]:
                raise ValueError(f"point {i}: w must increase, got {v[i - 1][0]} then {w}")
        if max(tau for _, tau in v[1:]) <= 0.0:
            raise ValueError("τ must be positive somewhere past the first point")
        return v

    @model_validator(mode="after")
    def _kind_and_points(self) -> UserConfig:
        if self.kind == "table" and self.points is None:
            raise ValueError("points: required when kind = 'table'")
        if self.kind != "table" and self.points is not None:
            raise ValueError(f"points: only with kind = 'table' (kind is {self.kind!r})")
        return self


KS = 20.0  # RISE's default ks: it holds a person whose torque rises with the velocity by up
# to (ks + 1)(1 − αr·dt) N·m·s/rad (docs/engine.md, "ks = 20, not 4")


def default_ks(alpha_r: float, inertia: float, rate: float) -> float:
    """RISE's ks when none is set: KS, or at a rate too slow for it the most the loop holds
    with the margin (:func:`sessions.stability.max_ks`, rounded down: 4.208 at 50 Hz)."""
    return min(KS, math.floor(stability.max_ks(alpha_r, inertia, 1.0 / rate) * 1e3) / 1e3)


class ControllerConfig(StrictModel):
    """Controller A, eq. (7) ("measured"), or controller B, eq. (23) ("rise").

    Their upper bounds depend on the loop rate and the inertia, so SessionConfig checks them
    (sessions/stability.py): k·dt/J ≤ 1; (ks + 1)·dt/J ≤ 2/(2 − αr·dt); αr·dt ≤ ½; β's
    sign-integral ripple within 1/20 of the torque limit."""

    kind: Literal["rise", "measured"] = "rise"
    ks: Positive = Field(
        KS,
        description="RISE gain ks (23); (ks + 1)·dt/J ≤ 2/(2 − αr·dt); left out: 20, or the most "
        "the loop holds at a slower rate",
    )
    beta: Positive = Field(0.5, description="RISE β1 + β2 (23), N·m/s; ripple ≤ 1/20 torque limit")
    alpha_r: Positive = Field(4.0, description="RISE αr (15), 1/s; αr·dt ≤ 1/2")
    k: Positive = Field(1.0, description="measured-torque gain k (7), N·m·s/rad; k·dt/J ≤ 1")


class FilterConfig(StrictModel):
    """Trajectory filter: p^n / (s + p)^n, n = 4 is (32) with p = 3, n = 3 is (33)."""

    order: Literal[3, 4] = 4
    pole: Positive = Field(3.0, le=200.0, description="repeated real pole p, rad/s")


class SeekerConfig(StrictModel):
    """Desired-trajectory generator: which extremum seeker and its parameters.

    Every seeker keeps its target within the bracket [γ1, γ3], the trainer's bounds for this
    person (``expand`` lets it move them outward in bounded steps, never past ``expand_limit``).
    """

    kind: Literal["sweep", "brent", "parabolic", "perturbation", "fixed"] = "sweep"
    bracket: tuple[Positive, Positive, Positive] = Field(
        (1.0, 3.5, 6.0),
        description="γ1 < γ2 < γ3: lower bound, best guess, upper bound, rad/s; the bounds are "
        "hard limits on every target",
    )
    rho: Positive = Field(1.0, le=5.0, description="ρ of the modified power p = τ·w^ρ (4)")
    objective: Literal["power", "surrogate"] = Field(
        "power", description="power: τ (or τ̂)·w^ρ; surrogate: eq. (31), the paper's Exp. 1"
    )
    measure: Literal["velocity", "desired"] = Field(
        "velocity",
        description="velocity: p = τ̂·w^ρ at the measured velocity, each power placed at the "
        "mean of w (unbiased by the tracking error); desired: p = τ̂·wd^ρ at the mean of wd, "
        "the paper's (13)",
    )
    filter: FilterConfig = FilterConfig()
    start_delay: NonNegative = Field(1.5, le=60.0, description="no measurement before this time, s")
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
        None,
        description="brent: first probe's distance from γ2 (default: a twentieth of the bracket)",
    )
    noise_k: NonNegative = Field(
        2.0, description="brent: points whose power differs by < k·σ are not told apart"
    )
    max_evaluations: int = Field(30, ge=3, le=1000)
    # the bracket as a bound
    expand: bool = Field(
        False, description="let the search move a bound outward when the optimum lies beyond it"
    )
    expand_limit: tuple[Positive, Positive] | None = Field(
        None,
        description="with expand: the lowest and highest velocity the bounds may move to, "
        "rad/s (never past 95 % of machine.max_velocity either)",
    )
    # sweep: learning p(w) from every sample
    sweep_rate: Positive = Field(
        0.15,
        le=2.0,
        description="sweep: speed of the candidate near the top, as a fraction of the velocity "
        "per second (faster where the power is clearly far from its maximum)",
    )
    power_tol: Positive = Field(
        0.005,
        le=0.1,
        description="sweep: converged once the optimum is known to within this fraction of "
        "the power (at two standard errors)",
    )
    # the track phase (numerical seekers, after convergence)
    track: bool = Field(
        True, description="after converging, follow the optimum if it moves (track phase)"
    )
    dither: NonNegative = Field(
        0.05, le=0.25, description="track: dither amplitude on the candidate, fraction of θ"
    )
    dither_period: Positive = Field(6.0, ge=1.0, le=120.0, description="track: dither period, s")
    track_memory: Positive = Field(
        20.0, ge=2.0, le=3600.0, description="track: time constant of the samples' weights, s"
    )
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
        if self.expand_limit is not None:
            lo, hi = self.expand_limit
            if not (lo <= self.bracket[0] and hi >= self.bracket[2]):
                raise ValueError(
                    f"expand_limit: must contain the bracket [{self.bracket[0]}, "
                    f"{self.bracket[2]}], got {[lo, hi]}"
                )
        if self.setpoint is not None and not self.bracket[0] <= self.setpoint <= self.bracket[2]:
            raise ValueError(
                f"setpoint: must lie within the bracket [{self.bracket[0]}, {self.bracket[2]}]"
            )
        if self.expand and self.expand_limit is None:
            raise ValueError(
                "expand_limit: required with expand = true (how far the bounds may move)"
            )
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
    def _default_ks(self) -> SessionConfig:
        """ks left at its default: :func:`default_ks` at this rate and inertia."""
        c = self.controller
        if "ks" not in c.model_fields_set:
            ks = default_ks(c.alpha_r, self.machine.inertia, self.rate)
            if ks != c.ks:
                object.__setattr__(self, "controller", c.model_copy(update={"ks": ks}))
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
