"""The controlled stop: how a session ends when nothing is broken (its duration is over, the
operator pressed stop) or when a soft limit is crossed (velocity over the limit, passivity
breached). A stop category 1, after IEC 60204-1: the motor stays under control while its torque
is taken away, then the drive is disabled.

- The torque ramps linearly from the last command to zero over ``duration`` (a person leaning
  on the handle is not dropped at once).
- The motor never drives during a stop: a ramp value that would push the handle along its
  motion (u·w > 0) is replaced by zero; only resisting torque remains.
- The velocity governor of the loop (:class:`sessions.limits.Limits`) still brakes above the
  machine's velocity limit, and the torque clamp still holds.
- The stop is over when the ramp has reached zero and the handle is within the velocity limit,
  or at the latest ``duration + grace`` seconds after it began.

The e-stop is not this: it writes zero torque at once (stop category 0).
"""

from __future__ import annotations

from sessions.limits import Limits


class StopRamp:
    __slots__ = ("u0", "steps", "k", "limits", "max_steps", "done")

    def __init__(
        self, u0: float, duration: float, dt: float, limits: Limits, grace: float = 2.0
    ) -> None:
        self.u0 = u0
        self.steps = max(1, round(duration / dt))
        self.max_steps = self.steps + round(grace / dt)
        self.k = 0
        self.limits = limits
        self.done = False

    def command(self, w: float) -> float:
        """The torque for this period, given the measured velocity."""
        k = self.k + 1
        self.k = k
        s = 1.0 - k / self.steps
        u = self.u0 * s if s > 0.0 else 0.0
        if u * w > 0.0:
            u = 0.0
        u = self.limits.apply(u, w)
        if u * w > 0.0:  # the governor only brakes; keep it that way
            u = 0.0
        if (s <= 0.0 and abs(w) <= self.limits.max_velocity) or k >= self.max_steps:
            self.done = True
            u = 0.0
        return u
