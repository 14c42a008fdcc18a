"""What a session produced, as plain validated data: the summary the store keeps, the API
returns and the dashboard shows. Built from a loop at the end of a session (or at any time).

Every field has a default, so a summary stored before a field existed still parses. The
fields that need the person's true power (``regret``) are None unless the loop was given the
truth (simulation, the sim machine): real hardware has none.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

from sessions.codes import Bound
from sessions.loop import Loop
from sessions.seekers.base import is_finite

Finite = Annotated[float, Field(allow_inf_nan=False)]


class SessionSummary(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    optimum_w: Finite | None = Field(
        None, gt=0, description="optimal velocity at the end (the setpoint to store), rad/s"
    )
    optimum_p: Finite | None = Field(None, description="power measured there, W")
    optimum_t: Finite | None = Field(
        None, ge=0, description="session time of that end optimum (the end of the session), s"
    )
    converged: bool = Field(
        False, description="the seeker finished its search on an optimum inside the bracket"
    )
    at_bound: Bound | None = Field(
        None,
        description="the best point is at this bound and the power still rises through it: "
        "not an optimum; widen the bracket",
    )
    t_converged: Finite | None = Field(
        None, ge=0, description="when the search first converged, s (None: never)"
    )
    wd_converged: Finite | None = Field(
        None, gt=0, description="the optimum first found, where the search converged, rad/s"
    )
    p_converged: Finite | None = Field(None, description="power measured there, W")
    target_min: Finite | None = Field(
        None, description="lowest candidate the seeker commanded, rad/s (within the bracket)"
    )
    target_max: Finite | None = Field(
        None, description="highest candidate the seeker commanded, rad/s (within the bracket)"
    )
    regret: Finite | None = Field(
        None,
        le=1.0,
        description="1 − ∫p(w(t),t)dt / ∫p*(t)dt after the start delay, true power at the "
        "actual velocity; None without the person's truth (real hardware)",
    )
    seeker: str = Field("", description="seeker kind")
    mean_power: Finite = Field(0.0, description="mean of τ·w (τ̂·w under RISE), W")
    peak_power: Finite = Field(0.0, description="peak of τ·w, W")
    work: Finite = Field(0.0, description="W(t) at the end (5), J")
    duration: Finite = Field(0.0, ge=0, description="s")
    passivity_min: Finite = Field(0.0, le=0, description="minimum of W(t), J")
    evaluations: int = Field(0, ge=0, description="powers the seeker measured")
    abort_reason: str | None = None


def _finite(x: float | None) -> float | None:
    return x if x is not None and is_finite(x) else None


def summarize(loop: Loop, abort_reason: str | None = None) -> SessionSummary:
    """The summary of what ``loop`` has run so far."""
    seeker = loop.seeker
    evs = seeker.evaluations
    optimum_w = _finite(seeker.optimum)
    optimum_p = _finite(seeker.optimum_power)
    if optimum_w is None and evs:  # still searching: where it stands
        optimum_w = seeker.target
        nearest = min(evs, key=lambda ev: (abs(ev.candidate - optimum_w), -ev.t))
        optimum_p = _finite(nearest.power)
    has_target = loop.k > 0 and is_finite(loop.target_min)
    return SessionSummary(
        optimum_w=optimum_w if optimum_w and optimum_w > 0 else None,
        optimum_p=optimum_p,
        optimum_t=loop.elapsed if optimum_w else None,
        converged=seeker.done and seeker.at_bound is None and seeker.t_converged is not None,
        at_bound=seeker.at_bound,  # type: ignore[arg-type]
        t_converged=seeker.t_converged,
        wd_converged=seeker.w_converged,
        p_converged=_finite(seeker.p_converged),
        target_min=loop.target_min if has_target else None,
        target_max=loop.target_max if has_target else None,
        regret=_finite(loop.regret),
        seeker=seeker.kind,
        mean_power=loop.mean_power,
        peak_power=loop.peak_power,
        work=loop.passivity.work,
        duration=loop.elapsed,
        passivity_min=loop.passivity.minimum,
        evaluations=len(evs),
        abort_reason=abort_reason,
    )
