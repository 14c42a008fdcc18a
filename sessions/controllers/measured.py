"""Controller A, for a machine that measures the user torque: eq. (7).

    u = -k e + J ad - τ                                                         (7)
Substituted in (6), J ė = -k e (8), so e(t) = e(0) exp(-k t / J) (9).
The seekers use the measured τ in p = τ·w^ρ (4).
"""

from __future__ import annotations


class MeasuredTorqueController:
    kind = "measured"
    needs_torque = True

    __slots__ = ("k", "inertia")

    def __init__(self, k: float, inertia: float) -> None:
        self.k = k
        self.inertia = inertia

    def begin(self, e0: float, ad0: float) -> None:
        pass

    def command(self, e: float, ad: float, tau: float) -> float:
        return -self.k * e + self.inertia * ad - tau  # (7)

    def commit(self, e: float, ad: float, tau: float, u: float, u_cmd: float, dt: float) -> float:
        """After the limits: the user torque the seekers see (here: measured)."""
        return tau
