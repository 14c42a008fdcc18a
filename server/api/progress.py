"""A user's progress across sessions (``/api/v1/users/{id}/progress``) and two sessions on one
time axis (``/api/v1/sessions/{id}/overlay``), for History. SI units; W/kg where the user's
body mass is known."""

from __future__ import annotations

import asyncio
import math
from datetime import datetime
from typing import Annotated, Literal

import numpy as np
from fastapi import APIRouter, Query

from server.api.deps import StoreDep, Viewer
from server.api.schemas import MAX_ID, Id
from server.api.workflow_schemas import OverlayOut, OverlaySession, ProgressOut, ProgressSession
from server.service.progress import (
    OVERLAY_UNITS,
    alignment,
    bucket_means,
    overlay_grid,
    progress,
)
from sessions.store import Store

router = APIRouter(tags=["progress"])
Align = Literal["start", "warmup", "seek", "train", "profile", "cooldown", "stop"]


@router.get(
    "/api/v1/users/{user_id}/progress", response_model=ProgressOut,
    summary="A user's ended sessions, oldest first: optima, powers (W and W/kg), profiles",
)  # fmt: skip
async def user_progress(
    user_id: Id,
    store: StoreDep,
    _: Viewer,
    since: datetime | None = None,
    until: datetime | None = None,
    limit: Annotated[int, Query(ge=1, le=5000)] = 500,
) -> ProgressOut:
    record, per = await asyncio.to_thread(
        progress, store, user_id, since=since, until=until, limit=limit
    )
    sessions = [
        ProgressSession(**p.model_dump(), **extra)
        for p, extra in zip(record.sessions, per, strict=True)
    ]
    return ProgressOut(user_id=record.user_id, body_mass_kg=record.body_mass_kg, sessions=sessions)


@router.get(
    "/api/v1/sessions/{session_id}/overlay", response_model=OverlayOut,
    summary="This session and another on one time axis: bucket means of w, wd, τ, τ·w, W",
)  # fmt: skip
async def overlay(
    session_id: Id,
    store: StoreDep,
    _: Viewer,
    other: Annotated[int, Query(alias="with", ge=1, le=MAX_ID, description="the other session")],
    points: Annotated[int, Query(ge=10, le=20_000)] = 1000,
    align: Annotated[
        Align, Query(description="t = 0 at the start, or at the first phase of this kind")
    ] = "start",
) -> OverlayOut:
    return await asyncio.to_thread(_overlay, store, (session_id, other), points, align)


def _clean(x: np.ndarray) -> list[float | None]:
    return [v if math.isfinite(v) else None for v in x.tolist()]


def _overlay(store: Store, ids: tuple[int, int], points: int, align: str) -> OverlayOut:
    offsets = (alignment(store, ids[0], align, "align"), alignment(store, ids[1], align, "with"))
    edges = overlay_grid(store, ids, offsets, points)
    out = []
    for sid, off in zip(ids, offsets, strict=True):
        means, used = bucket_means(store, sid, off, edges)
        out.append(OverlaySession(session_id=sid, offset=off, samples=used,
                                  channels={k: _clean(v) for k, v in means.items()}))  # fmt: skip
    centres = 0.5 * (edges[1:] + edges[:-1])
    return OverlayOut(align=align, t=centres.tolist(), units=OVERLAY_UNITS, sessions=out)
