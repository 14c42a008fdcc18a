"""The people who exercise, and their optimal setpoints."""

from __future__ import annotations

import asyncio
from typing import Annotated

from fastapi import APIRouter, Query, Request, Response

from server.auth import Trainer, Viewer
from server.schemas import MAX_ID, Id, SetpointIn, Setpoints, UserIn, UserPatch
from sessions.store import Page, SetpointRecord, UserRecord

router = APIRouter(prefix="/api/v1/users", tags=["users"])


@router.get("", response_model=Page[UserRecord], summary="Users by name, paginated")
async def list_users(
    request: Request,
    _: Viewer,
    search: Annotated[str | None, Query(max_length=200)] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    offset: Annotated[int, Query(ge=0, le=MAX_ID)] = 0,
) -> Page[UserRecord]:
    store = request.app.state.runtime.store
    return await asyncio.to_thread(store.users.list, search=search, limit=limit, offset=offset)


@router.post("", response_model=UserRecord, status_code=201, summary="Add a user")
async def create_user(request: Request, body: UserIn, _: Trainer) -> UserRecord:
    store = request.app.state.runtime.store
    return await asyncio.to_thread(
        lambda: store.users.create(
            body.name,
            notes=body.notes,
            body_mass_kg=body.body_mass_kg,
            limb=body.limb,
            sim_profile=body.sim_profile,
        )
    )


@router.get("/{user_id}", response_model=UserRecord, summary="One user")
async def get_user(request: Request, user_id: Id, _: Viewer) -> UserRecord:
    return await asyncio.to_thread(request.app.state.runtime.store.users.get, user_id)


@router.patch("/{user_id}", response_model=UserRecord, summary="Edit a user")
async def patch_user(request: Request, user_id: Id, body: UserPatch, _: Trainer) -> UserRecord:
    store = request.app.state.runtime.store
    changes = body.model_dump(exclude_unset=True)
    return await asyncio.to_thread(lambda: store.users.update(user_id, **changes))


@router.delete("/{user_id}", status_code=204, summary="Delete a user with their sessions")
async def delete_user(request: Request, user_id: Id, _: Trainer) -> Response:
    runtime = request.app.state.runtime
    active = runtime.control.active
    if active is not None and active.user_id == user_id:
        from fastapi import HTTPException

        raise HTTPException(409, detail="this user's session is running")
    await asyncio.to_thread(runtime.store.users.delete, user_id)
    return Response(status_code=204)


@router.get("/{user_id}/setpoints", response_model=Setpoints, summary="Current optimum and history")
async def setpoints(request: Request, user_id: Id, _: Viewer) -> Setpoints:
    store = request.app.state.runtime.store

    def read() -> Setpoints:
        store.users.get(user_id)  # 404 for an unknown user
        return Setpoints(
            current=store.setpoints.current(user_id), history=store.setpoints.history(user_id)
        )

    return await asyncio.to_thread(read)


@router.post(
    "/{user_id}/setpoints", response_model=SetpointRecord, status_code=201,
    summary="Set a user's optimum by hand",
)  # fmt: skip
async def set_setpoint(
    request: Request, user_id: Id, body: SetpointIn, _: Trainer
) -> SetpointRecord:
    store = request.app.state.runtime.store
    return await asyncio.to_thread(
        lambda: store.setpoints.record(user_id, body.velocity, power=body.power, seeker="manual")
    )
