"""The machine: status (backend, armed, fault, loop timing), e-stop and reset."""

from __future__ import annotations

from fastapi import APIRouter

from server.api.deps import MachineDep, Trainer, Viewer
from server.api.schemas import MachineOut

router = APIRouter(prefix="/api/v1/machine", tags=["machine"])


@router.get("", response_model=MachineOut, summary="Backend, state, fault, loop timing")
async def machine(service: MachineDep, _: Viewer) -> MachineOut:
    return service.status()


@router.post("/estop", status_code=202, summary="Emergency stop: zero torque now, latched")
async def estop(service: MachineDep, _: Trainer) -> dict[str, str]:
    service.estop()
    return {"status": "estopped"}


@router.post(
    "/reset", status_code=202, summary="Clear a latched e-stop or fault (never starts motion)"
)
async def reset(service: MachineDep, _: Trainer) -> dict[str, str]:
    await service.reset()
    return {"status": "reset"}
