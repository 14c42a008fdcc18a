"""What the web process holds while it runs: built by the composition root (:mod:`server.app`)
in its lifespan, kept on ``app.state.runtime``, handed to the routes as dependencies
(:mod:`server.api.deps`) and to the dashboard as it is: every part typed."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from server.security import LoginLimiter
from server.service import LiveHub, MachineService
from server.service.accounts import AccountEvents, LiveGate
from server.settings import Settings
from sessions.store import Store

if TYPE_CHECKING:  # the composition root imports both; the service never imports webui
    from sessions.machine.odrive.emulator import EmulatorProcess
    from webui.dashboard import Dashboard


@dataclass(eq=False)
class Runtime:
    settings: Settings
    store: Store
    hub: LiveHub
    machine: MachineService
    limiter: LoginLimiter
    recovered: list[int] = field(default_factory=list)  # sessions a crash left running
    emulator: EmulatorProcess | None = None  # the emulated ODrive of ``odrive-emulator``
    dashboard: Dashboard | None = None
    # changes to accounts, told at once to open connections (live sockets, the dashboard)
    accounts: AccountEvents = field(default_factory=AccountEvents)
    live_gate: LiveGate = field(default_factory=lambda: LiveGate(8, 64))  # (caps: settings)
