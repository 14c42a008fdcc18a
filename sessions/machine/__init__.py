"""The machine a session drives: one lifecycle and read → update → write cycle (:mod:`.base`),
described by plain data (:mod:`.spec`), with two backends behind it: the simulator (:mod:`.sim`)
and an ODrive over its ASCII protocol (:mod:`.odrive`, with the emulated ODrive on a
pseudo-terminal that the tests and the demo drive it against)."""

from __future__ import annotations

from sessions.machine.base import Machine, MachineError, MachineState
from sessions.machine.spec import MachineSpec, SimFault, check_controller


def make_machine(spec: MachineSpec) -> Machine:
    """The backend a spec names, not yet connected."""
    if spec.kind == "odrive":
        from sessions.machine.odrive import OdriveMachine

        return OdriveMachine(spec)
    from sessions.machine.sim import SimMachine

    return SimMachine(spec.sim_fault)


__all__ = [
    "Machine",
    "MachineError",
    "MachineSpec",
    "MachineState",
    "SimFault",
    "check_controller",
    "make_machine",
]
