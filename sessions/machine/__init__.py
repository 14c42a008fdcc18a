"""The machine a session drives: one lifecycle and read → update → write cycle (:mod:`.base`),
three implementations behind it: the simulator (:mod:`.sim`), an ODrive over its ASCII protocol
(:mod:`.odrive`), and an ODrive emulated on a pseudo-terminal for the tests and the demo
(:mod:`.emulator`)."""

from __future__ import annotations

from sessions.machine.base import Machine, MachineError, MachineState
from sessions.machine.spec import MachineSpec


def make_machine(spec: MachineSpec) -> Machine:
    """The backend a spec names, not yet connected."""
    if spec.kind == "odrive":
        from sessions.machine.odrive import OdriveMachine

        return OdriveMachine(spec)
    from sessions.machine.sim import SimMachine

    return SimMachine()


__all__ = ["Machine", "MachineError", "MachineSpec", "MachineState", "make_machine"]
