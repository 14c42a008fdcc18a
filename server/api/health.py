"""``/healthz``: liveness, without a login (the Docker health check, load balancers)."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

from fastapi import APIRouter, Request

from server.api.schemas import Health

try:
    VERSION = version("ergoseek")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    VERSION = "0+unknown"

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health, summary="Liveness (no login)")
async def healthz(request: Request) -> Health:
    runtime = getattr(request.app.state, "runtime", None)  # (None until the lifespan built it)
    if runtime is None:
        settings = request.app.state.settings
        return Health(
            status="degraded",
            machine=settings.machine,
            worker="starting",
            database="closed",
            version=VERSION,
        )
    worker = runtime.machine.status().state
    ok = worker not in ("lost", "starting", "closed")
    return Health(
        status="ok" if ok else "degraded",
        machine=runtime.settings.machine,
        worker=worker,
        database=runtime.store.dialect,
        version=VERSION,
    )
