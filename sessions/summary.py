"""What a session produced, as plain validated data: the summary the store keeps, the API
returns and the dashboard shows. Built from a loop at the end of a session (or at any time)."""

from __future__ import annotations

import math
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

from sessions.loop import Loop

Finite = Annotated[float, Field(allow_inf_nan=False)]


class SessionSummary(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    optimum_w: Finite | None = Field(None, gt=0, description="optimal velocity found, rad/s")
    optimum_p: Finite | None = Field(None, description="power measured there, W")
    converged: bool = Field(False, description="the seeker finished its search")
    seeker: str = Field("", description="seeker kind")
    mean_power: Finite = Field(0.0, description="mean of τ·w (τ̂·w under RISE), W")
    peak_power: Finite = Field(0.0, description="peak of τ·w, W")
    work: Finite = Field(0.0, description="W(t) at the end (5), J")
    duration: Finite = Field(0.0, ge=0, description="s")
    passivity_min: Finite = Field(0.0, le=0, description="minimum of W(t), J")
    evaluations: int = Field(0, ge=0, description="candidates measured")
    abort_reason: str | None = None


def summarize(loop: Loop, abort_reason: str | None = None) -> SessionSummary:
    """The summary of what ``loop`` has run so far."""
    seeker = loop.seeker
    evs = seeker.evaluations
    optimum_w = optimum_p = None
    if evs:
        optimum_w = seeker.target
        nearest = min(evs, key=lambda ev: (abs(ev.candidate - optimum_w), -ev.t))
        optimum_p = nearest.power if math.isfinite(nearest.power) else None
    return SessionSummary(
        optimum_w=optimum_w if optimum_w and optimum_w > 0 else None,
        optimum_p=optimum_p,
        converged=seeker.done,
        seeker=seeker.kind,
        mean_power=loop.mean_power,
        peak_power=loop.peak_power,
        work=loop.passivity.work,
        duration=loop.elapsed,
        passivity_min=loop.passivity.minimum,
        evaluations=len(evs),
        abort_reason=abort_reason,
    )
