"""What each phase of a session produced, from its telemetry: one definition for the
simulation, the server (from the store) and the exports.

- :func:`phase_spans`: the runner's stages grouped into phases, each from its first period to
  the next phase's first period (the last to the end of the telemetry);
- :func:`summarize_phase`: totals as :func:`sessions.exports.data.totals` defines them (mean and
  peak of τ·w, work = the rise of W (5)), the optimum the phase ended on (seek, train), the
  work intervals' own totals (train) and the velocity-spectrum fit (profile,
  :func:`sessions.profile.fit_profile` over the plan the runner followed).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sessions.exports.data import Phase, totals
from sessions.profile import (
    Estimate,
    ProfileCurve,
    ProfileError,
    ProfileFit,
    ProfilePlan,
    ProfileStep,
    StepMean,
    fit_profile,
    step_samples,
)
from sessions.protocol.stage import Stage

OPTIMUM_KINDS = ("seek", "train")  # phases whose optimum is the seeker's


@dataclass(frozen=True)
class PhaseSpan:
    index: int
    kind: str
    name: str
    start: float  # s, the phase's first period
    end: float  # s, the next phase's first period (or the end of the data)
    stages: tuple[Stage, ...]
    optimum: float | None = None  # rad/s: the seeker's optimum as the phase ended
    at_bound: str | None = None  # lower, upper: the seeker's best point at that edge as it ended


@dataclass(frozen=True)
class PhaseResult:
    """One phase's summary (SI units); ``detail`` is JSON-ready."""

    index: int
    kind: str
    name: str
    start: float
    end: float
    mean_power: float
    peak_power: float
    work: float
    mean_w: float
    optimum_w: float | None
    at_bound: str | None = None
    profile: ProfileFit | None = None
    detail: dict[str, Any] = field(default_factory=dict)

    def export_phase(self) -> Phase:
        """As the exports take it (a FIT lap, a row of the report's phase table)."""
        return Phase(
            name=self.name, start=self.start, end=self.end, kind=self.kind,
            mean_power=self.mean_power, peak_power=self.peak_power, work=self.work,
            optimum_w=self.optimum_w, at_bound=self.at_bound,
        )  # fmt: skip


def phase_spans(
    stages: Sequence[Stage],
    end: float,
    final_optimum: float | None = None,
    final_at_bound: str | None = None,
) -> list[PhaseSpan]:
    """The phases the stages describe, in order, up to session time ``end`` (phases that had
    not begun by then, or never ran a period, are left out). ``final_optimum`` and
    ``final_at_bound``: the seeker's optimum and bound at the session's end (the summary's),
    for the last phase; every other phase takes them from the next phase's first stage."""
    groups: list[list[Stage]] = []
    for st in stages:
        if st.segment == 0 or not groups or groups[-1][0].phase != st.phase:
            groups.append([st])
        else:
            groups[-1].append(st)
    spans = []
    for i, g in enumerate(groups):
        start = g[0].start
        stop = groups[i + 1][0].start if i + 1 < len(groups) else end
        stop = min(stop, end)
        if stop <= start:
            continue
        later = groups[i + 1][0] if i + 1 < len(groups) else None
        optimum = later.optimum if later is not None else final_optimum
        bound = later.at_bound if later is not None else final_at_bound
        head = g[0]
        seeks = head.kind in OPTIMUM_KINDS
        spans.append(PhaseSpan(head.phase, head.kind, head.name, start, stop, tuple(g),
                               optimum if seeks else None, bound if seeks else None))  # fmt: skip
    return spans


def _finite(x: float) -> float:
    return x if math.isfinite(x) else 0.0


def profile_plan(stage: Stage) -> ProfilePlan:
    """The velocity-spectrum plan a profile phase's first stage carries."""
    return ProfilePlan(
        tuple(ProfileStep(i, v, s, st, e) for i, (v, s, st, e) in enumerate(stage.profile))
    )


def interval_totals(cols: Mapping[str, np.ndarray], span: PhaseSpan) -> list[dict[str, Any]]:
    """Each work interval of a train phase: its span and totals."""
    out = []
    for i, st in enumerate(span.stages):
        if st.role != "work":
            continue
        stop = span.stages[i + 1].start if i + 1 < len(span.stages) else span.end
        tot = totals(cols, st.start, min(stop, span.end))
        out.append({
            "interval": st.interval, "start": st.start, "end": min(stop, span.end),
            "velocity": st.velocity, "mean_power": _finite(tot.mean_power),
            "peak_power": _finite(tot.peak_power), "work": _finite(tot.work),
            "mean_w": _finite(tot.mean_w),
        })  # fmt: skip
    return out


def fit_phase_profile(
    cols: Mapping[str, np.ndarray], span: PhaseSpan, model: str = "auto"
) -> tuple[ProfileFit | None, str | None]:
    """The profile fit of a profile phase (None and the reason when it cannot be fitted)."""
    head = span.stages[0]
    if not head.profile:
        return None, "no plan recorded"
    plan = profile_plan(head)
    if span.end < span.start + plan.duration - 1e-6:
        return None, f"the phase ended at {span.end - span.start:.1f} s of {plan.duration:.1f} s"
    q = cols.get("q")
    steps = step_samples(plan, cols["t"], cols["tau"], cols["w"], q, t0=head.phase_start)
    try:
        return fit_profile(steps, model=model), None  # type: ignore[arg-type]
    except ProfileError as exc:
        return None, str(exc)


def summarize_phase(
    cols: Mapping[str, np.ndarray], span: PhaseSpan, *, profile_model: str = "auto"
) -> PhaseResult:
    """The summary of one phase from full-rate telemetry columns t, q, w, tau, W."""
    tot = totals(cols, span.start, span.end)
    detail: dict[str, Any] = {"stages": [st.to_dict() for st in span.stages]}
    fit = None
    if span.kind == "train":
        detail["intervals"] = interval_totals(cols, span)
    elif span.kind == "profile":
        fit, problem = fit_phase_profile(cols, span, profile_model)
        detail["profile"] = fit.to_dict() if fit is not None else None
        if problem is not None:
            detail["profile_error"] = problem
    return PhaseResult(
        index=span.index, kind=span.kind, name=span.name, start=span.start, end=span.end,
        mean_power=_finite(tot.mean_power), peak_power=_finite(tot.peak_power),
        work=_finite(tot.work), mean_w=_finite(tot.mean_w), optimum_w=span.optimum,
        at_bound=span.at_bound, profile=fit, detail=detail,
    )  # fmt: skip


def profile_from_dict(d: Mapping[str, Any]) -> ProfileFit:
    """A :class:`ProfileFit` back from its ``to_dict()`` (as stored)."""

    def est(x: Mapping[str, float] | None) -> Estimate | None:
        return None if x is None else Estimate(x["value"], x["low"], x["high"], x["stderr"])

    curve = d["curve"]
    return ProfileFit(
        model=d["model"],
        tau0=est(d["tau0"]),  # type: ignore[arg-type]
        wmax=est(d["wmax"]),  # type: ignore[arg-type]
        a=est(d.get("a")),
        pmax=est(d["pmax"]),  # type: ignore[arg-type]
        w_opt=est(d["w_opt"]),  # type: ignore[arg-type]
        confidence=d["confidence"],
        dof=d["dof"],
        reduced_chi2=d["reduced_chi2"] if d["reduced_chi2"] is not None else math.nan,
        hill_p_value=d["hill_p_value"],
        steps=tuple(
            StepMean(s["velocity"], s["w"], s["tau"], s["tau_se"], s["samples"]) for s in d["steps"]
        ),
        curve=ProfileCurve(**{k: np.asarray(v, dtype=float) for k, v in curve.items()}),
        warnings=tuple(d.get("warnings", ())),
    )
