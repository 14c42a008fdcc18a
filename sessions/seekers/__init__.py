"""Extremum seekers: desired-trajectory generators that find w*, behind one interface."""

from __future__ import annotations

from sessions.config import SeekerConfig
from sessions.seekers.base import Evaluation, Seeker, SeekerProgress
from sessions.seekers.brent import BrentSeeker
from sessions.seekers.fixed import FixedSeeker
from sessions.seekers.parabolic import ParabolicAsPrintedSeeker, ParabolicSeeker
from sessions.seekers.perturbation import PerturbationSeeker
from sessions.seekers.sweep import SweepSeeker


def make_seeker(
    cfg: SeekerConfig, dt: float, max_velocity: float, *, as_printed: bool = False
) -> Seeker:
    """The seeker a configuration names; ``as_printed`` runs Appendix A's Step 7 as printed."""
    if cfg.kind == "parabolic":
        cls = ParabolicAsPrintedSeeker if as_printed else ParabolicSeeker
        return cls(cfg, dt, max_velocity)
    if cfg.kind == "brent":
        return BrentSeeker(cfg, dt, max_velocity)
    if cfg.kind == "sweep":
        return SweepSeeker(cfg, dt, max_velocity)
    if cfg.kind == "perturbation":
        return PerturbationSeeker(cfg, dt, max_velocity)
    return FixedSeeker(cfg, dt, max_velocity)


__all__ = ["Evaluation", "Seeker", "SeekerProgress", "make_seeker"]
