"""The composition root of the web process: what it is made of, and how the parts are wired.

    store ──► MachineService (worker ◄─► pump ──► store, LiveHub) ──► REST API, dashboard

:func:`create_app` builds the FastAPI app; its lifespan opens the store (upgrading the schema
and aborting sessions a crash left running), builds the machine (for ``odrive-emulator``, an
emulated ODrive on a pseudo-terminal first), starts its worker and pump, then the dashboard;
and on shutdown brings the torque to zero, ends the running session as stopped and lets the
worker exit, with nothing lost. The routes reach the parts through :mod:`server.api.deps`,
the dashboard through the same :class:`server.runtime.Runtime`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator
from pathlib import Path

from fastapi import FastAPI

from server import api, guard
from server.api.health import VERSION
from server.runtime import Runtime
from server.security import LoginLimiter, device_key
from server.service import LiveHub, MachineService
from server.service.accounts import LiveGate
from server.settings import Settings
from sessions.machine.odrive.emulator import EmulatorConfig, EmulatorProcess
from sessions.store import Store, display_url, open_server_store
from sessions.store.database import sqlite_path

log = logging.getLogger("ergoseek.server")


def _emulator(settings: Settings) -> EmulatorProcess | None:
    """The emulated ODrive ``odrive-emulator`` drives: the real protocol over a real pty."""
    if settings.machine != "odrive-emulator":
        return None
    spec = settings.machine_spec("(the emulator's pty)")
    return EmulatorProcess(EmulatorConfig.for_rig(spec, settings.machine_config()))


def _store_dir(store: Store) -> Path | None:
    """Where the server may keep a file of its own: beside the SQLite database, if it is one."""
    path = sqlite_path(store.url)
    return path.parent if path is not None else None


def _machine(
    settings: Settings, store: Store, hub: LiveHub, emulator: EmulatorProcess | None
) -> MachineService:
    spec = settings.machine_spec(emulator.path if emulator is not None else None)
    return MachineService(store, spec, settings.rig(spec), hub, settings.worker)


@contextlib.asynccontextmanager
async def _running(app: FastAPI, settings: Settings) -> AsyncIterator[Runtime]:
    """Everything the web process runs, built in order and taken down in reverse."""
    store, recovered = await asyncio.to_thread(
        open_server_store, settings.store_url(), password_hasher=settings.password_hash.hasher()
    )
    if recovered:
        log.warning("sessions %s were left running by a crash: marked aborted", recovered)
    log.info("store %s", display_url(store.url))
    hub = LiveHub(settings.rate)
    emulator = machine = None
    try:
        emulator = await asyncio.to_thread(_emulator, settings)
        machine = _machine(settings, store, hub, emulator)
        key = await asyncio.to_thread(device_key, _store_dir(store))
        limiter = LoginLimiter(settings.login_attempts, settings.login_window_s, key)
        await asyncio.to_thread(store.tokens.purge)  # expired and revoked logins
        gate = LiveGate(settings.live_max_per_account, settings.live_max_total)
        runtime = Runtime(
            settings, store, hub, machine, limiter, recovered, emulator, live_gate=gate
        )
        await machine.open()
        if settings.dashboard:
            from webui.dashboard import start_dashboard

            runtime.dashboard = await start_dashboard(runtime)
        app.state.runtime = runtime
        yield runtime
    finally:
        runtime_now = getattr(app.state, "runtime", None)
        if runtime_now is not None and runtime_now.dashboard is not None:
            await asyncio.to_thread(runtime_now.dashboard.stop)
        if machine is not None:
            await machine.close()
        if emulator is not None:
            await asyncio.to_thread(emulator.close)
        await asyncio.to_thread(store.close)


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        async with _running(app, settings):
            yield

    app = FastAPI(
        title="ergoseek",
        version=VERSION,
        summary="Extremum-seeking exercise machine: sessions, users, setpoints, live telemetry.",
        description="The API is SI throughout: velocities rad/s, torques N·m, powers W (and W/kg "
        "where a user's body mass is known), work J, times s. The dashboard converts for the "
        "person reading (rpm by default: `/api/v1/accounts/me/preferences`).",
        lifespan=lifespan,
        docs_url=None,  # served by server.api.docs: local assets, a strict policy
        redoc_url=None,
    )
    app.state.settings = settings
    guard.install(app, settings)
    api.mount(app)
    if settings.dashboard:
        from webui.pages import router as pages

        app.include_router(pages)
    return app
