"""Hard limits enforced inside every loop step, whatever controller computed u.

- |u| ≤ max_torque: the command is clamped.
- |w| ≤ max_velocity: above it a governor overrides the command with braking torque that
  grows with the overspeed (full torque at 0.5 rad/s over), as a drive's velocity limiter does.
  Its gain is a proportional velocity gain like controller A's k, so it obeys the same bound
  (sessions/stability.py, S5): at most J/dt, the deadbeat gain. Below ~100 Hz (J = 0.1) that,
  not the 0.5 rad/s span, sets it: a stiffer governor would brake with full torque, overshoot
  below the limit and chatter between zero and the clamp every period.
Each step reports which limit acted, as bit flags, so the worker can raise events and stop.
"""

from __future__ import annotations

import math

from sessions.codes import TORQUE_LIMIT, VELOCITY_LIMIT

__all__ = ["GOVERNOR_SPAN", "TORQUE_LIMIT", "VELOCITY_LIMIT", "Limits"]

GOVERNOR_SPAN = 0.5  # rad/s of overspeed for full braking torque


class Limits:
    __slots__ = ("max_torque", "max_velocity", "gain", "flags")

    def __init__(self, max_torque: float, max_velocity: float, max_gain: float = math.inf) -> None:
        self.max_torque = max_torque
        self.max_velocity = max_velocity
        self.gain = min(max_torque / GOVERNOR_SPAN, max_gain)  # N·m·s/rad
        self.flags = 0

    def apply(self, u: float, w: float) -> float:
        flags = 0
        vmax = self.max_velocity
        if w > vmax:
            u = min(u, -self.gain * (w - vmax))
            flags |= VELOCITY_LIMIT
        elif w < -vmax:
            u = max(u, self.gain * (-vmax - w))
            flags |= VELOCITY_LIMIT
        umax = self.max_torque
        if u > umax:
            u = umax
            flags |= TORQUE_LIMIT
        elif u < -umax:
            u = -umax
            flags |= TORQUE_LIMIT
        self.flags = flags
        return u
