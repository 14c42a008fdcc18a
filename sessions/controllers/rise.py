"""Controller B, RISE with a torque observer, for a machine without a torque sensor.

    u(t) = J ad(t) - [J ad(t0) - (ks+1) e(t0)] - (ks+1) e(t)
           - ∫t0..t (ks+1) αr e dσ - ∫t0..t (β1+β2) sgn(e) dσ                    (23)
    τ̂ = -u + J ad                                                              (28)
The bracket makes u(t0) = 0. The two integrals are left-rectangle sums at the loop rate
(∫t0..tk uses e(t0) … e(tk-1)), so u(t0) = 0 holds exactly in discrete time; sgn(0) = 0.

Anti-windup (the paper has no limits): when the applied u is clamped below the command,
the integrals do not grow further in the direction that pushed it there. The observer uses the
torque actually applied, since (28) follows from (1) with the real u.
"""

from __future__ import annotations


class RiseController:
    kind = "rise"
    needs_torque = False

    __slots__ = ("ks1", "ks1_ar", "beta", "inertia", "offset", "integral")

    def __init__(self, ks: float, beta: float, alpha_r: float, inertia: float) -> None:
        self.ks1 = ks + 1.0
        self.ks1_ar = (ks + 1.0) * alpha_r
        self.beta = beta
        self.inertia = inertia
        self.offset = 0.0
        self.integral = 0.0

    def begin(self, e0: float, ad0: float) -> None:
        self.offset = self.inertia * ad0 - self.ks1 * e0  # the bracket of (23)
        self.integral = 0.0

    def command(self, e: float, ad: float, tau: float) -> float:
        return self.inertia * ad - self.offset - self.ks1 * e - self.integral  # (23)

    def commit(self, e: float, ad: float, tau: float, u: float, u_cmd: float, dt: float) -> float:
        sgn = 1.0 if e > 0.0 else (-1.0 if e < 0.0 else 0.0)
        d = (self.ks1_ar * e + self.beta * sgn) * dt
        # u falls as the integral grows: hold it if that would deepen a clamp.
        if not ((u_cmd > u and d < 0.0) or (u_cmd < u and d > 0.0)):
            self.integral += d
        return -u + self.inertia * ad  # (28)
