"""An ODrive (firmware 0.5.x, v3.x boards) over its ASCII protocol: the facts of the protocol
both ends share (:mod:`.protocol`), the machine backend the worker drives (:mod:`.backend`),
and an emulated device on a pseudo-terminal for the tests and the demo (:mod:`.emulator`)."""

from __future__ import annotations

from sessions.machine.odrive.backend import OdriveMachine

__all__ = ["OdriveMachine"]
