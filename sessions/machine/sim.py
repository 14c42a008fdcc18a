"""The simulated machine: the engine's plant (1) and a simulated user, one period per cycle.

The worker paces the cycles in real time; the plant advances exactly one loop period per
``write`` (zero-order hold of u, as a drive applies a setpoint), so a session on this backend
is the same computation as :func:`sessions.simulation.run_simulation` with the same config,
step for step, whatever the scheduling jitter. The simulated person follows the session's cues
(:meth:`Machine.follow`): relaxes in a rest, and at the end of a session once the handle is
brought to rest. The handle has a torque sensor: ``read``
returns the user torque at the current state, so controller A (7) works here.
"""

from __future__ import annotations

from sessions.config import SessionConfig
from sessions.machine.base import Machine
from sessions.people import SimulatedUser
from sessions.plant import Plant
from sessions.protocol.cues import CuedPerson


class SimMachine(Machine):
    kind = "sim"
    has_torque_sensor = True

    def __init__(self) -> None:
        super().__init__()
        self.plant: Plant | None = None
        self.user: SimulatedUser | CuedPerson | None = None
        self.dt = 0.0

    def _connect(self) -> None:
        pass

    def _arm(self, cfg: SessionConfig) -> None:
        self.dt = cfg.dt
        person = SimulatedUser(cfg.user, cfg.dt, cfg.seed)
        cues = self.cues
        self.user = person if cues is None else CuedPerson(person, cues, cfg.dt)
        self.plant = Plant(cfg.machine.inertia)

    def _read(self) -> tuple[float, float, float]:
        plant = self.plant
        assert plant is not None and self.user is not None
        tau = plant.sample_torque(self.user)
        return plant.q, plant.w, tau

    def _write(self, u: float) -> None:
        plant, user = self.plant, self.user
        assert plant is not None and user is not None
        plant.advance(u, self.dt, user)
        user.advance(self.dt)

    def _zero(self) -> None:
        pass  # torque acts only through _write; nothing is held between cycles

    def _disarm(self) -> None:
        pass

    def _reset(self) -> None:
        pass

    def _close(self) -> None:
        self.plant = None
        self.user = None
