"""The web process: one FastAPI app whose lifespan opens the store (upgrading the schema and
aborting sessions a crash left running), starts the machine's worker (and, for
``odrive-emulator``, the emulator on a pseudo-terminal), the control pump and the dashboard;
and on shutdown brings the torque to zero, ends the running session as stopped and lets the
worker exit, with nothing lost."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
from collections.abc import AsyncIterator
from importlib.metadata import PackageNotFoundError, version
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

from server.auth import LoginLimiter
from server.control import BusyError, Control, RequestError
from server.live import LiveHub
from server.schemas import Health, MachineOut
from server.settings import Settings
from sessions.machine.spec import MachineSpec
from sessions.store import (
    ConflictError,
    NotFoundError,
    Store,
    StoreValueError,
    display_url,
    open_server_store,
)
from sessions.worker.handle import WorkerError

log = logging.getLogger("ergoseek.server")

try:
    VERSION = version("ergoseek")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    VERSION = "0+unknown"


class Runtime:
    """Everything the routes share, created in the lifespan and kept on ``app.state``."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.store: Store = None  # type: ignore[assignment]
        self.control: Control = None  # type: ignore[assignment]
        self.hub = LiveHub(settings.rate)
        self.limiter = LoginLimiter(settings.login_attempts, settings.login_window_s)
        self.emulator: Any = None
        self.dashboard: Any = None
        self.recovered: list[int] = []

    def machine_spec(self) -> MachineSpec:
        s = self.settings
        if s.machine == "sim":
            return MachineSpec(kind="sim")
        device = s.device
        if s.machine == "odrive-emulator":  # the real protocol, over a real pty
            from sessions.machine.odrive.emulator import EmulatorConfig, EmulatorProcess

            self.emulator = EmulatorProcess(EmulatorConfig(inertia=s.inertia))
            device = self.emulator.path
        return MachineSpec(
            kind="odrive",
            device=device,
            gear_ratio=s.gear_ratio,
            direction=s.direction,
            reply_timeout=s.reply_timeout,
            watchdog_timeout=s.watchdog_timeout,
        )

    def machine_status(self) -> MachineOut:
        s = self.settings
        control = self.control
        worker = control.worker if control is not None else None
        st = worker.status() if worker is not None else None
        state = "lost" if control is None or control.lost else (st.state if st else "starting")
        active = control.active if control is not None else None
        return MachineOut(
            backend=s.machine,
            state=state,
            armed=state in ("running", "stopping"),
            fault=(
                control.lost if control is not None and control.lost else (st.fault if st else None)
            ),
            session_id=active.db_id if active is not None else None,
            heartbeat_age_ms=(
                st.heartbeat_age * 1e3 if st and st.heartbeat_age is not None else None
            ),
            limits={"max_torque": s.max_torque, "max_velocity": s.max_velocity},
            rate_hz=s.rate,
            timing=dataclasses.asdict(st.timing) if st and st.timing else None,
            realtime=dataclasses.asdict(st.realtime) if st and st.realtime else None,
        )


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()
    runtime = Runtime(settings)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        store, recovered = await asyncio.to_thread(open_server_store, settings.store_url())
        runtime.store, runtime.recovered = store, recovered
        if recovered:
            log.warning("sessions %s were left running by a crash: marked aborted", recovered)
        log.info("store %s", display_url(store.url))
        try:
            spec = await asyncio.to_thread(runtime.machine_spec)
            runtime.control = Control(settings, store, spec, runtime.hub)
            await runtime.control.open()
            if settings.dashboard:
                from webui.dashboard import start_dashboard

                runtime.dashboard = await start_dashboard(app, runtime)
            yield
        finally:
            if runtime.dashboard is not None:
                await asyncio.to_thread(runtime.dashboard.stop)
            if runtime.control is not None:
                await runtime.control.close()
            if runtime.emulator is not None:
                await asyncio.to_thread(runtime.emulator.close)
            await asyncio.to_thread(store.close)

    app = FastAPI(
        title="ergoseek",
        version=VERSION,
        summary="Extremum-seeking exercise machine: sessions, users, setpoints, live telemetry.",
        lifespan=lifespan,
    )
    app.state.runtime = runtime
    _errors(app)

    from server.api import accounts, auth, live, machine, sessions, users

    for module in (auth, accounts, users, sessions, machine, live):
        app.include_router(module.router)

    @app.get("/healthz", response_model=Health, tags=["health"], summary="Liveness (no login)")
    async def healthz() -> Health:
        ms = runtime.machine_status() if runtime.control is not None else None
        worker = ms.state if ms else "starting"
        ok = worker not in ("lost", "starting", "closed") and runtime.store is not None
        return Health(
            status="ok" if ok else "degraded",
            machine=settings.machine,
            worker=worker,
            database=runtime.store.dialect if runtime.store is not None else "closed",
            version=VERSION,
        )

    if settings.dashboard:
        from webui.pages import router as pages

        app.include_router(pages)
    return app


def _errors(app: FastAPI) -> None:
    def problem(status: int, detail: Any) -> JSONResponse:
        return JSONResponse(status_code=status, content={"detail": detail})

    @app.exception_handler(StoreValueError)
    async def _store_value(_: Request, exc: StoreValueError) -> JSONResponse:
        loc = ["body", *exc.field.split(".")]
        return problem(422, [{"loc": loc, "msg": exc.reason, "type": "value_error"}])

    @app.exception_handler(RequestError)
    async def _request(_: Request, exc: RequestError) -> JSONResponse:
        loc = ["body", *exc.field.split(".")]
        return problem(422, [{"loc": loc, "msg": exc.reason, "type": "value_error"}])

    @app.exception_handler(NotFoundError)
    async def _not_found(_: Request, exc: NotFoundError) -> JSONResponse:
        return problem(404, str(exc))

    async def _conflict(_: Request, exc: Exception) -> JSONResponse:
        return problem(409, str(exc))

    for conflict in (ConflictError, BusyError, WorkerError):  # running, latched, worker down
        app.add_exception_handler(conflict, _conflict)

    @app.exception_handler(RequestValidationError)
    async def _validation(_: Request, exc: RequestValidationError) -> JSONResponse:
        detail = [
            {
                "loc": list(e["loc"]),
                "msg": e["msg"].removeprefix("Value error, "),
                "type": e["type"],
            }
            for e in exc.errors()
        ]
        return problem(422, detail)
