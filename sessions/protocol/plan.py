"""What each phase of a protocol does, stretch by stretch: the segments the runner walks.

A *segment* is a stretch of a phase with one way of making the reference and one effort cue:

    HOLD   γ held at a velocity (the trajectory filter brings wd there smoothly);
    RAMP   γ moving linearly from where the reference is to a velocity over the segment;
    SEEK   the seeker's own reference (the search, as without a protocol);
    TRACK  γ = the seeker's target, the seeker told every period (training at the optimum,
           following it where the seeker tracks);
    REST   γ = 0 until the handle has been at rest long enough (the end of a cool-down or of
           the runner's own stop): then the torque may be released.

:func:`plan_phase` turns a phase's configuration into its segments when the phase begins,
from what the session knows then (the bracket, the velocity the reference is at). Pure: the
same arguments give the same plan, so the store, the report and the tests can rebuild it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from sessions.config import FilterConfig
from sessions.profile import ProfilePlan, plan_profile
from sessions.protocol.config import (
    REST_GRACE,
    REST_HOLD,
    STOP,
    STOP_DECELERATION,
    Cooldown,
    Profile,
    Seek,
    Train,
    Warmup,
)

HOLD, RAMP, SEEK, TRACK, REST = 0, 1, 2, 3, 4
MODES = ("hold", "ramp", "seek", "track", "rest")
WORK = math.nan  # a HOLD/TRACK velocity resolved when the segment begins: the work velocity


@dataclass(frozen=True, slots=True)
class Segment:
    role: str  # warmup, seek, countdown, work, rest, step, cooldown, relax, stop
    mode: int  # HOLD, RAMP, SEEK, TRACK, REST
    duration: float  # s; REST: the longest it may last
    gamma: float = 0.0  # HOLD: the velocity; RAMP: where it ends; WORK: resolved at start
    effort: float = 1.0  # the cue at the start
    effort_end: float | None = None  # RAMP: the cue at the end (None: constant)
    interval: int = 0  # train: the work interval (1-based); profile: the step (1-based)
    minimum: float = 0.0  # REST: s held at least


@dataclass(frozen=True, slots=True)
class PhasePlan:
    segments: tuple[Segment, ...]
    profile: ProfilePlan | None = None

    @property
    def duration(self) -> float:
        return sum(s.duration for s in self.segments)


def plan_phase(
    ph: Any, bracket: tuple[float, float, float], velocity: float, filt: FilterConfig
) -> PhasePlan:
    """The segments of phase ``ph`` begun with the reference at ``velocity`` (rad/s), for a
    session with seeker bracket ``bracket`` (γ1, γ2, γ3) and trajectory filter ``filt``."""
    if isinstance(ph, Warmup):
        v = ph.velocity if ph.velocity is not None else bracket[0]
        if ph.ramp > 0:
            segs = [Segment("warmup", RAMP, ph.ramp, v, ph.effort)]
            if ph.duration > ph.ramp:
                segs.append(Segment("warmup", HOLD, ph.duration - ph.ramp, v, ph.effort))
            return PhasePlan(tuple(segs))
        return PhasePlan((Segment("warmup", HOLD, ph.duration, v, ph.effort),))
    if isinstance(ph, Seek):
        return PhasePlan((Segment("seek", SEEK, ph.duration),))
    if isinstance(ph, Train):
        return PhasePlan(tuple(train_segments(ph)))
    if isinstance(ph, Profile):
        lo, hi = ph.span((bracket[0], bracket[2]))
        plan = plan_profile(
            (lo, hi), ph.count, ph.hold, order=ph.order, seed=ph.seed,
            start_velocity=velocity, filt=filt,
        )  # fmt: skip
        segs = tuple(
            Segment("step", HOLD, s.end - s.start, s.velocity, ph.effort, interval=s.index + 1)
            for s in plan.steps
        )
        return PhasePlan(segs, plan)
    if isinstance(ph, Cooldown):
        return PhasePlan(
            (
                Segment("cooldown", RAMP, ph.duration, 0.0, ph.effort, effort_end=0.0),
                rest_segment(ph.hold),
            )
        )
    raise ValueError(f"not a phase: {ph!r}")


def train_segments(ph: Train) -> list[Segment]:
    """A countdown, then per interval work and rest; the next countdown ends each rest."""
    work_mode = TRACK if ph.track else HOLD
    rest, cd, out = ph.rest, ph.countdown, []
    if cd > 0:
        out.append(Segment("countdown", HOLD, cd, WORK, ph.rest_effort, interval=1))
    for k in range(1, ph.intervals + 1):
        out.append(Segment("work", work_mode, ph.work, WORK, 1.0, interval=k))
        last = k == ph.intervals
        calm = rest if last else rest - cd
        if calm > 0:
            out.append(Segment("rest", HOLD, calm, ph.rest_velocity, ph.rest_effort, interval=k))
        if not last and cd > 0:
            out.append(Segment("countdown", HOLD, cd, WORK, ph.rest_effort, interval=k + 1))
    return out


def rest_segment(minimum: float) -> Segment:
    """At rest, relaxed, until the handle has stayed still REST_HOLD s (at least ``minimum``)."""
    hold = max(minimum, REST_HOLD)
    return Segment("relax", REST, hold + REST_GRACE, 0.0, 0.0, minimum=hold)


def stop_plan(velocity: float) -> PhasePlan:
    """The runner's own stop from ``velocity``: γ down to 0 at STOP_DECELERATION, then rest."""
    ramp = abs(velocity) / STOP_DECELERATION
    segs = [Segment(STOP, RAMP, ramp, 0.0, 0.0)] if ramp > 0 else []
    return PhasePlan((*segs, rest_segment(0.0)))
