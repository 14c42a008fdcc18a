"""The cues a protocol gives the person, and a simulated person who follows them.

The runner's ``effort`` (0 … 1) is what the person is asked for: full in a work interval, a
seek or a profile step, easy in a warm-up, nothing (relax) in a rest or at the end of a
cool-down. On real hardware the dashboard shows it; it never changes what the machine does. A
simulated person (:class:`CuedPerson`) follows it as a person would, not at once: their torque
is scaled by a level that follows the cue with a first-order response (``response`` s).
"""

from __future__ import annotations

import math
from typing import Any, Protocol

from sessions.people import SimulatedUser

RESPONSE = 0.3  # s: how fast a person changes their effort when asked


class Cues(Protocol):
    effort: float


class CuedPerson:
    """A :class:`~sessions.people.SimulatedUser` whose torque follows the cues' effort. It
    offers the plant what the person offers (``torque(q, w)``, ``advance(dt)``) and everything
    else of the person (their truth, for scoring) unchanged."""

    def __init__(
        self, person: SimulatedUser, cues: Cues, dt: float, response: float = RESPONSE
    ) -> None:
        self.person = person
        self.cues = cues
        self.level = float(cues.effort)
        self.gain = -math.expm1(-dt / response)  # exact for a cue held over the period
        inner = person.torque

        def torque(q: float, w: float) -> float:
            return self.level * inner(q, w)

        self.torque = torque

    def advance(self, dt: float) -> None:
        self.person.advance(dt)
        self.level += (self.cues.effort - self.level) * self.gain

    def __getattr__(self, name: str) -> Any:
        return getattr(self.person, name)
