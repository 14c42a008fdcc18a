"""The web process's services, with no HTTP and no viser in them: what the REST API
(:mod:`server.api`) and the dashboard (:mod:`webui`) both call.

    machine   MachineService: one machine's worker, its running session, start/stop/e-stop/reset
    pump      the task that records the worker's telemetry and events, and publishes them
    live      LiveHub: fan-out of records and events to subscribers that never hold anyone up
    session   the running session as the web process follows it
    users     what a trainer enters about a user; adding and editing users
"""

from __future__ import annotations

from server.service.live import LiveHub, Subscription, serve_subscription
from server.service.machine import BusyError, Live, MachineService, MachineStatus
from server.service.pump import Pump
from server.service.session import ActiveSession, LiveSession

__all__ = [
    "ActiveSession",
    "BusyError",
    "Live",
    "LiveHub",
    "LiveSession",
    "MachineService",
    "MachineStatus",
    "Pump",
    "Subscription",
    "serve_subscription",
]
