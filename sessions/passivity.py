"""Passivity of the machine with respect to the user (5): W(t) = ∫ τ w dt ≥ -c².

W is the work the user has done on the machine. A passive machine never returns more energy
to the user than the user put in, beyond a bounded c²: W(t) < -c² means the motor is
driving the person, and the session must stop.
"""

from __future__ import annotations


class PassivityMonitor:
    __slots__ = ("c2", "work", "minimum", "breached")

    def __init__(self, c2: float) -> None:
        self.c2 = c2
        self.work = 0.0
        self.minimum = 0.0
        self.breached = False

    def add(self, tau: float, w: float, dt: float) -> float:
        """Add one period of τ·w (5); returns W."""
        work = self.work + tau * w * dt
        self.work = work
        if work < self.minimum:
            self.minimum = work
            if work < -self.c2:
                self.breached = True
        return work
