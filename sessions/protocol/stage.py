"""What the runner reports each time a segment begins: plain frozen data, the same in a
simulation's log, in the worker's event to its parent, in the store and on the live stream."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True, slots=True)
class Stage:
    """A segment has begun (``segment == 0``: a new phase, the one before ended at ``start``).

    Times are session seconds: ``start`` is the time of the segment's first period; ``end`` and
    ``phase_end`` are the planned ends (a seek phase may end sooner, once converged; a rest at
    the end of a cool-down once the handle is still). Velocities are rad/s."""

    phase: int  # index in the protocol; the runner's own stop is len(phases)
    kind: str  # warmup, seek, train, profile, cooldown, stop
    name: str  # the phase's name, or its kind and number
    segment: int  # index within the phase
    role: str  # warmup, seek, countdown, work, rest, step, cooldown, relax, stop
    mode: str  # hold, ramp, seek, track, rest (sessions.protocol.plan.MODES)
    start: float
    end: float
    phase_start: float
    phase_end: float
    velocity: float  # γ held (ramp: where it ends; seek: the seeker's first candidate)
    effort: float  # the cue: the effort asked of the person, 0 … 1
    interval: int = 0  # train: the work interval, 1-based; profile: the step, 1-based
    intervals: int = 0  # train: work intervals; profile: steps
    next_kind: str | None = None  # the phase after this one
    next_name: str | None = None
    optimum: float | None = None  # the seeker's optimum at this time, if it has one
    at_bound: str | None = None  # the seeker's at_bound at this time (lower, upper), if any
    profile: tuple[tuple[float, float, float, float], ...] = ()  # first segment of a profile:
    # its plan's steps (velocity, start, settled, end), times from the phase's start

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Stage:
        """Back from :meth:`to_dict` (as stored); unknown keys are ignored, missing numbers
        (null: not finite) read as NaN."""
        names = {f.name for f in dataclasses.fields(cls)}
        values = {k: v for k, v in d.items() if k in names}
        for key in ("start", "end", "phase_start", "phase_end", "velocity", "effort"):
            if values.get(key) is None:
                values[key] = math.nan
        values["profile"] = tuple(tuple(float(x) for x in s) for s in values.get("profile") or ())
        return cls(**values)

    def to_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out["profile"] = [list(s) for s in self.profile]
        for key, value in out.items():
            if isinstance(value, float) and not math.isfinite(value):
                out[key] = None
        return out
