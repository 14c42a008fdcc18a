"""The machine: status (backend, armed, fault, loop timing), e-stop and reset."""

from __future__ import annotations

import dataclasses

from fastapi import APIRouter, Request

from server.auth import Trainer, Viewer
from server.schemas import MachineOut

router = APIRouter(prefix="/api/v1/machine", tags=["machine"])


@router.get("", response_model=MachineOut, summary="Backend, state, fault, loop timing")
async def machine(request: Request, _: Viewer) -> MachineOut:
    return request.app.state.runtime.machine_status()


@router.post("/estop", status_code=202, summary="Emergency stop: zero torque now, latched")
async def estop(request: Request, _: Trainer) -> dict[str, str]:
    request.app.state.runtime.control.estop()
    return {"status": "estopped"}


@router.post(
    "/reset", status_code=202, summary="Clear a latched e-stop or fault (never starts motion)"
)
async def reset(request: Request, _: Trainer) -> dict[str, str]:
    await request.app.state.runtime.control.reset()
    return {"status": "reset"}


def plain(obj: object) -> dict[str, object] | None:
    return None if obj is None else dataclasses.asdict(obj)  # type: ignore[call-overload]
