"""The machine tests' parts: an ODrive emulated in a process of its own on a real
pseudo-terminal (:mod:`sessions.machine.odrive.emulator`), shared by a module's tests; a
module that needs another rig (gear ratio, direction) overrides ``emu``."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from sessions.machine.odrive.emulator import EmulatorConfig, EmulatorProcess


@pytest.fixture(scope="module")
def emu() -> Iterator[EmulatorProcess]:
    with EmulatorProcess(EmulatorConfig()) as e:
        yield e
