"""The people who exercise, and their optimal setpoints."""

from __future__ import annotations

import asyncio
from typing import Annotated

from fastapi import APIRouter, HTTPException, Query, Response

from server.api.deps import MachineDep, StoreDep, Trainer, Viewer
from server.api.schemas import MAX_ID, Id, SetpointIn, Setpoints, UserIn, UserPatch
from server.service.users import check_setpoint, create_user, update_user
from sessions.store import Page, SetpointRecord, Store, UserRecord

router = APIRouter(prefix="/api/v1/users", tags=["users"])


@router.get("", response_model=Page[UserRecord], summary="Users by name, paginated")
async def list_users(
    store: StoreDep,
    _: Viewer,
    search: Annotated[str | None, Query(max_length=200)] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    offset: Annotated[int, Query(ge=0, le=MAX_ID)] = 0,
) -> Page[UserRecord]:
    return await asyncio.to_thread(store.users.list, search=search, limit=limit, offset=offset)


@router.post("", response_model=UserRecord, status_code=201, summary="Add a user")
async def create(body: UserIn, store: StoreDep, _: Trainer) -> UserRecord:
    return await asyncio.to_thread(create_user, store, body)


@router.get("/{user_id}", response_model=UserRecord, summary="One user")
async def get_user(user_id: Id, store: StoreDep, _: Viewer) -> UserRecord:
    return await asyncio.to_thread(store.users.get, user_id)


@router.patch("/{user_id}", response_model=UserRecord, summary="Edit a user")
async def patch_user(user_id: Id, body: UserPatch, store: StoreDep, _: Trainer) -> UserRecord:
    return await asyncio.to_thread(update_user, store, user_id, body)


@router.delete("/{user_id}", status_code=204, summary="Delete a user with their sessions")
async def delete_user(user_id: Id, store: StoreDep, machine: MachineDep, _: Trainer) -> Response:
    if machine.running_user() == user_id:
        raise HTTPException(409, detail="this user's session is running")
    await asyncio.to_thread(store.users.delete, user_id)
    return Response(status_code=204)


@router.get("/{user_id}/setpoints", response_model=Setpoints, summary="Current optimum and history")
async def setpoints(user_id: Id, store: StoreDep, _: Viewer) -> Setpoints:
    return await asyncio.to_thread(_setpoints, store, user_id)


def _setpoints(store: Store, user_id: int) -> Setpoints:
    store.users.get(user_id)  # 404 for an unknown user
    return Setpoints(
        current=store.setpoints.current(user_id), history=store.setpoints.history(user_id)
    )


@router.post(
    "/{user_id}/setpoints", response_model=SetpointRecord, status_code=201,
    summary="Set a user's optimum by hand",
)  # fmt: skip
async def set_setpoint(
    user_id: Id, body: SetpointIn, store: StoreDep, machine: MachineDep, _: Trainer
) -> SetpointRecord:
    check_setpoint(body.velocity, machine.rig)
    return await asyncio.to_thread(
        lambda: store.setpoints.record(user_id, body.velocity, power=body.power, seeker="manual")
    )
