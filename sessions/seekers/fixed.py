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
        sp = self.cfg.setpoint if self.cfg.setpoint is not None else self.cfg.bracket[1]
        return self.clamp(sp)

    def plan(self, lo: float, guess: float, hi: float) -> Plan:
        sp = self.setpoint()
        self.optimum = sp
        self.bracket = (sp, sp)
        while True:
            ev = yield sp
            self.optimum_power = ev.power

    def fraction(self) -> float:
        return 1.0
