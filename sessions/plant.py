"""The machine model (1): J ẇ = τ(q, w) + u, with q̇ = w.

Integration: classical Runge-Kutta (RK4) over each loop period, the motor torque u held
constant over the period (zero-order hold, as a drive applies a setpoint) and the user torque
τ(q, w) evaluated at every stage, so τ changing with w and q inside the period is followed.
Why RK4 and not sub-stepped Euler: the stiffest rate is |dτ/dw|/J (≈ 15 1/s for the default Hill
user), so λ·dt ≈ 0.015 at 1 kHz and RK4's local error is ~(λ dt)⁵ ≈ 1e-9 relative: exact
to the precision anyone can measure, at four torque evaluations a period. The linear user makes
(1) a linear ODE with a closed-form solution; the tests check RK4 against it.

The same RK4 weights integrate the true user power τ·w, so the simulator knows the user's
passivity integral (5) exactly, independently of what the controller estimates.
"""

from __future__ import annotations

from sessions.people import SimulatedUser


class Plant:
    """Shaft state (q, w) of eq. (1) driven by a simulated user and a motor torque."""

    __slots__ = ("inertia", "q", "w", "user_work", "user_torque")

    def __init__(self, inertia: float, q0: float = 0.0, w0: float = 0.0) -> None:
        self.inertia = inertia
        self.q = q0
        self.w = w0
        self.user_work = 0.0  # ∫ τ w dt, the true (5)
        self.user_torque = 0.0  # τ at the last sample

    def sample_torque(self, user: SimulatedUser) -> float:
        """τ at the current state: what a torque sensor would read now."""
        self.user_torque = user.torque(self.q, self.w)
        return self.user_torque

    def advance(self, u: float, dt: float, user: SimulatedUser) -> None:
        """Integrate (1) over one period with u held; call :meth:`sample_torque` first."""
        torque = user.torque
        inv_j = 1.0 / self.inertia
        h = 0.5 * dt
        q1, w1 = self.q, self.w
        t1 = self.user_torque
        a1 = (t1 + u) * inv_j
        q2, w2 = q1 + h * w1, w1 + h * a1
        t2 = torque(q2, w2)
        a2 = (t2 + u) * inv_j
        q3, w3 = q1 + h * w2, w1 + h * a2
        t3 = torque(q3, w3)
        a3 = (t3 + u) * inv_j
        q4, w4 = q1 + dt * w3, w1 + dt * a3
        t4 = torque(q4, w4)
        a4 = (t4 + u) * inv_j
        s = dt / 6.0
        self.q = q1 + s * (w1 + 2.0 * w2 + 2.0 * w3 + w4)
        self.w = w1 + s * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        self.user_work += s * (t1 * w1 + 2.0 * t2 * w2 + 2.0 * t3 * w3 + t4 * w4)
