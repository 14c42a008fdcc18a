"""Your account's preferences (``/api/v1/accounts/me/preferences``): how the dashboard shows
velocities (rpm by default, or rad/s). The REST API itself always speaks SI (rad/s)."""

from __future__ import annotations

import asyncio

from fastapi import APIRouter

from server.api.deps import StoreDep, Viewer
from server.api.workflow_schemas import Preferences, PreferencesIn

router = APIRouter(prefix="/api/v1/accounts/me", tags=["accounts"])


@router.get("/preferences", response_model=Preferences, summary="Your display preferences")
async def get_preferences(store: StoreDep, account: Viewer) -> Preferences:
    record = await asyncio.to_thread(store.preferences.get, account.id)
    return Preferences(velocity_unit=record.velocity_unit)


@router.put("/preferences", response_model=Preferences, summary="Set your display preferences")
async def put_preferences(body: PreferencesIn, store: StoreDep, account: Viewer) -> Preferences:
    record = await asyncio.to_thread(
        lambda: store.preferences.set(account.id, velocity_unit=body.velocity_unit)
    )
    return Preferences(velocity_unit=record.velocity_unit)
