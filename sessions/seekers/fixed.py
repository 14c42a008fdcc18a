"""Hold one setpoint, typically the user's stored optimum, and keep measuring p there."""

from __future__ import annotations

from sessions.seekers.base import FilteredSeeker, Plan


class FixedSeeker(FilteredSeeker):
    kind = "fixed"
    __slots__ = ()

    def begin(self, w0: float) -> None:
        super().begin(w0)
        self.done = True  # nothing to seek; evaluations keep coming, one per window
        self.reason = "fixed setpoint"

    def setpoint(self) -> float:
        return self.cfg.setpoint if self.cfg.setpoint is not None else self.cfg.bracket[1]

    def plan(self) -> Plan:
        sp = self.setpoint()
        self.bracket = (sp, sp)
        while True:
            yield sp

    def fraction(self) -> float:
        return 1.0
