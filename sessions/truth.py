"""What the engine may know of the person's true power, and the regret it scores with it.

Only a simulated person has a truth: :class:`sessions.people.SimulatedUser` satisfies
:class:`Truth`. A loop is given one (``Loop(cfg, truth=user)`` or ``loop.attach_truth(user)``)
in simulation and on the sim machine; on real hardware there is none and every figure that
needs it (``regret``) is None.

    regret = 1 − ∫ p(w(t), t) dt / ∫ p*(t) dt,  over [start_delay, end]          (issue 14)

with p the true modified power (4) at the *actual* velocity, p* the best the person could give
at that time. The integrals are sampled every 10 ms (the power changes over seconds; the
loop's period is too fine to matter), so the meter costs the 1 kHz loop almost nothing.
"""

from __future__ import annotations

from typing import Protocol


class Truth(Protocol):
    def true_power(self, w: float, rho: float = 1.0, t: float | None = None) -> float:
        """p(w, t) without noise or ripple; t = None: now."""
        ...

    def optimum(self, rho: float = 1.0, t: float | None = None) -> tuple[float, float]:
        """(w*, p*) at t; t = None: now."""
        ...


SAMPLE = 0.01  # s between samples of the regret's integrals


class RegretMeter:
    __slots__ = ("truth", "rho", "start", "every", "countdown", "power", "best")

    def __init__(self, truth: Truth, rho: float, start: float, dt: float) -> None:
        self.truth = truth
        self.rho = rho
        self.start = start
        self.every = max(1, round(SAMPLE / dt))
        self.countdown = 0
        self.power = 0.0  # Σ p(w(t), t)
        self.best = 0.0  # Σ p*(t)

    def add(self, t: float, w: float) -> None:
        """One period at time t, actual velocity w (the truth is read at its own 'now')."""
        if t < self.start:
            return
        self.countdown -= 1
        if self.countdown > 0:
            return
        self.countdown = self.every
        truth = self.truth
        self.power += truth.true_power(w, self.rho)
        self.best += truth.optimum(self.rho)[1]

    @property
    def regret(self) -> float | None:
        return 1.0 - self.power / self.best if self.best > 0.0 else None
