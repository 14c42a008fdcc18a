"""An ODrive v3.x (firmware 0.5.x) emulated on a pseudo-terminal: the ASCII protocol subset a
torque-controlled rig uses, in front of the engine's plant (1) and a simulated person.

    device (.device)   the property tree, axis state machine, limits, watchdog and physics
    ascii  (.ascii)    one line in, the replies out: one function per command letter
    pty    (.pty)      the pseudo-terminal, line framing, fault injection, observation
    process (.process) the emulator in a process of its own (tests, benchmarks, the server)
"""

from __future__ import annotations

from sessions.machine.odrive.emulator.device import (
    AXIS_COUNT,
    DEVICE_FAULTS,
    FACTORY,
    Device,
    EmulatorConfig,
    EmulatorSnapshot,
)
from sessions.machine.odrive.emulator.process import EmulatorProcess, device_priority
from sessions.machine.odrive.emulator.pty import INJECTIONS, Injection, OdriveEmulator

__all__ = [
    "AXIS_COUNT",
    "DEVICE_FAULTS",
    "FACTORY",
    "INJECTIONS",
    "Device",
    "EmulatorConfig",
    "EmulatorProcess",
    "EmulatorSnapshot",
    "Injection",
    "OdriveEmulator",
    "device_priority",
]
