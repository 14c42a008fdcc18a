"""What a protocol asks of the seeker, behind one small interface: where its optimum is, and
whether it can follow that optimum during training (a seeker's ``track`` phase, issue 14).
A seeker without tracking is held at its optimum instead."""

from __future__ import annotations

from sessions.codes import BOUNDS
from sessions.seekers import Seeker


def optimum(seeker: Seeker) -> float | None:
    """The seeker's best estimate of the optimal velocity now (rad/s), None before it has one:
    its setpoint once its search has ended, else where the search stands."""
    found = getattr(seeker, "optimum", None)
    if isinstance(found, float):
        return found
    return seeker.target if seeker.evaluations or seeker.done else None


def at_bound(seeker: Seeker) -> str | None:
    """Where the seeker's search stands against the trainer's bracket now: "lower" or "upper"
    when its best point is at that edge with the power still rising outward, else None."""
    side = getattr(seeker, "at_bound", None)
    return side if side in BOUNDS else None


def can_track(seeker: Seeker) -> bool:
    """Whether the seeker follows a moving optimum after convergence (its track phase)."""
    return bool(getattr(seeker, "tracking", False))
