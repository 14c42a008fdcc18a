"""The REST API under ``/api/v1`` and the live WebSocket: thin routes over the services, their
dependencies (:mod:`.deps`), schemas (:mod:`.schemas`) and error responses (:mod:`.errors`)."""

from __future__ import annotations

from fastapi import FastAPI

from server.api import (
    accounts,
    auth,
    docs,
    errors,
    exports,
    health,
    live,
    machine,
    preferences,
    progress,
    protocols,
    sessions,
    users,
)

ROUTERS = (
    auth.router, preferences.router, accounts.router, users.router, sessions.router,
    exports.router, progress.router, protocols.router, machine.router, live.router,
)  # fmt: skip


def mount(app: FastAPI) -> None:
    """Every route of the API, its error handlers and ``/healthz`` on ``app``."""
    errors.install(app)
    for router in ROUTERS:
        app.include_router(router)
    app.include_router(health.router)
    docs.mount(app)
