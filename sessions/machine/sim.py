"""The simulated machine: the engine's plant (1) and a simulated user, one period per cycle.

The worker paces the cycles in real time; the plant advances exactly one loop period per
``write`` (zero-order hold of u, as a drive applies a setpoint), so a session on this backend
is the same computation as :func:`sessions.simulation.run_simulation` with the same config,
step for step, whatever the scheduling jitter. The simulated person follows the session's cues
(:meth:`Machine.follow`): relaxes in a rest, and at the end of a session once the handle is
brought to rest. The handle has a torque sensor: ``read``
returns the user torque at the current state, so controller A (7) works here.

A :class:`sessions.machine.spec.SimFault` makes the simulator misbehave from a session time
on, through the same path real faults take: the measurement reads NaN (a broken sensor), the
torque sensor reads 1e308 N·m (an absurd person), or the worker process dies or exits.
"""

from __future__ import annotations

import math
import os

from sessions.config import SessionConfig
from sessions.machine.base import Machine
from sessions.machine.spec import SimFault
from sessions.people import SimulatedUser
from sessions.plant import Plant
from sessions.protocol.cues import CuedPerson
from sessions.truth import Truth

HUGE_TORQUE = 1e308  # N·m: finite, and every product the loop forms with it overflows


class SimMachine(Machine):
    kind = "sim"
    has_torque_sensor = True

    def __init__(self, fault: SimFault | None = None) -> None:
        super().__init__()
        self.plant: Plant | None = None
        self.user: SimulatedUser | CuedPerson | None = None
        self.dt = 0.0
        self.fault = fault
        self.steps = 0  # periods written this session
        self.fault_step = -1  # the period the fault starts (-1: none)

    def _connect(self) -> None:
        pass

    def _arm(self, cfg: SessionConfig) -> None:
        self.dt = cfg.dt
        person = SimulatedUser(cfg.user, cfg.dt, cfg.seed)
        cues = self.cues
        self.user = person if cues is None else CuedPerson(person, cues, cfg.dt)
        self.plant = Plant(cfg.machine.inertia)
        self.steps = 0
        self.fault_step = -1 if self.fault is None else round(self.fault.at / cfg.dt)

    def truth(self) -> Truth | None:
        return self.user

    def _read(self) -> tuple[float, float, float]:
        plant = self.plant
        assert plant is not None and self.user is not None
        tau = plant.sample_torque(self.user)
        if 0 <= self.fault_step <= self.steps:
            return self._faulty(plant.q, plant.w, tau)
        return plant.q, plant.w, tau

    def _faulty(self, q: float, w: float, tau: float) -> tuple[float, float, float]:
        """The reading once the injected fault has started."""
        assert self.fault is not None
        kind = self.fault.kind
        if kind == "worker-abort":
            os.abort()  # the process dies here, as a crash in native code would
        if kind == "worker-exit":
            raise SystemExit(f"injected fault worker-exit at t = {self.fault.at:g} s")
        nan = math.nan
        if kind == "nan-angle":
            return nan, w, tau
        if kind == "nan-velocity":
            return q, nan, tau
        if kind == "nan-torque":
            return q, w, nan
        return q, w, HUGE_TORQUE

    def _write(self, u: float) -> None:
        plant, user = self.plant, self.user
        assert plant is not None and user is not None
        plant.advance(u, self.dt, user)
        user.advance(self.dt)
        self.steps += 1

    def _zero(self) -> None:
        pass  # torque acts only through _write; nothing is held between cycles

    def _disarm(self) -> None:
        pass

    def _reset(self) -> None:
        pass

    def _close(self) -> None:
        self.plant = None
        self.user = None
