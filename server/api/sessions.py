"""Sessions: start (with a protocol or a template), stop, list, one session's summary,
evaluations, phases, live state, telemetry (decimated JSON or full-rate CSV) and events. SI
units throughout (rad/s, N·m, W, J, s)."""

from __future__ import annotations

import asyncio
import json
import math
from datetime import datetime
from typing import Annotated

from fastapi import APIRouter, Query
from fastapi.responses import Response, StreamingResponse

from server.api.deps import MachineDep, StoreDep, Trainer, Viewer
from server.api.schemas import MAX_ID, Id, SessionOut, SessionStart, TelemetryOut
from server.service import phases as phase_service
from server.service.templates import resolve_template
from sessions.codes import SessionStatus
from sessions.store import EventRecord, Page, PhaseRecord, SessionRecord, Store
from sessions.telemetry import NAMES, UNITS

router = APIRouter(prefix="/api/v1/sessions", tags=["sessions"])


@router.post(
    "", response_model=SessionRecord, status_code=201, summary="Start a session",
    responses={409: {"description": "a session is running, or the machine must be reset"}},
)  # fmt: skip
async def start_session(
    body: SessionStart, machine: MachineDep, store: StoreDep, account: Trainer
) -> SessionRecord:
    if body.template_id is not None:
        body = await asyncio.to_thread(resolve_template, store, body, account)
    return await machine.start(body, account.id)


@router.get("", response_model=Page[SessionRecord], summary="Sessions, newest first")
async def list_sessions(
    store: StoreDep,
    _: Viewer,
    user_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
    status: Annotated[list[SessionStatus] | None, Query()] = None,
    since: datetime | None = None,
    until: datetime | None = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 50,
    offset: Annotated[int, Query(ge=0, le=MAX_ID)] = 0,
) -> Page[SessionRecord]:
    return await asyncio.to_thread(
        lambda: store.sessions.list(
            user_id=user_id, status=status, since=since, until=until, limit=limit, offset=offset
        )
    )


@router.get("/{session_id}", response_model=SessionOut, summary="Summary, evaluations, live state")
async def get_session(
    session_id: Id, store: StoreDep, machine: MachineDep, _: Viewer
) -> SessionOut:
    detail = await asyncio.to_thread(store.sessions.detail, session_id)
    return SessionOut(
        session=detail.session,
        evaluations=detail.evaluations,
        events=detail.events,
        phases=detail.phases,
        live=machine.live(session_id),
        hint=hint(detail.session),
    )


def hint(s: SessionRecord) -> str | None:
    """What the trainer should know about a session's result."""
    if s.at_bound is not None:
        lo, _, hi = s.config["seeker"]["bracket"]
        edge = hi if s.at_bound == "upper" else lo
        return (
            f"the best point is at the {s.at_bound} bound of the bracket ({edge:g} rad/s) and "
            "the power still rises beyond it: not stored as the optimum; widen the bracket"
        )
    return None


@router.get(
    "/{session_id}/phases", response_model=list[PhaseRecord],
    summary="The protocol's phases: spans (s), powers (W), work (J), optimum (rad/s) and its bound",
)  # fmt: skip
async def session_phases(session_id: Id, store: StoreDep, _: Viewer) -> list[PhaseRecord]:
    return await asyncio.to_thread(_phases, store, session_id)


def _phases(store: Store, session_id: int) -> list[PhaseRecord]:
    return phase_service.session_phases(store, session_id)


@router.post(
    "/{session_id}/stop", status_code=202, summary="Stop a running session (torque ramped out)"
)
async def stop_session(
    session_id: Id, store: StoreDep, machine: MachineDep, _: Trainer
) -> dict[str, str]:
    await asyncio.to_thread(store.sessions.get, session_id)  # 404 if unknown
    machine.stop(session_id)
    return {"status": "stopping"}


@router.get(
    "/{session_id}/events", response_model=list[EventRecord], summary="Faults, e-stops, limits"
)
async def session_events(
    session_id: Id, store: StoreDep, _: Viewer, kind: str | None = None
) -> list[EventRecord]:
    return await asyncio.to_thread(lambda: store.sessions.events(session_id, kind=kind))


@router.get(
    "/{session_id}/telemetry", response_model=TelemetryOut,
    summary="Telemetry as JSON, decimated to a point budget (min/max kept)",
)  # fmt: skip
async def telemetry(
    session_id: Id,
    store: StoreDep,
    _: Viewer,
    points: Annotated[int, Query(ge=10, le=200_000)] = 2000,
    start: Annotated[float | None, Query(ge=0, allow_inf_nan=False)] = None,
    end: Annotated[float | None, Query(ge=0, allow_inf_nan=False)] = None,
) -> Response:
    body = await asyncio.to_thread(_telemetry_json, store, session_id, start, end, points)
    # built here (not validated again by the response model, which documents it)
    return Response(body, media_type="application/json")


def _telemetry_json(
    store: Store, session_id: int, start: float | None, end: float | None, points: int
) -> bytes:
    data = store.telemetry.load(session_id, start=start, end=end, points=points)
    cols = data.columns
    body = {
        "session_id": session_id,
        "samples": data.samples,
        "decimated": data.decimated,
        "units": dict(UNITS),
        # NaN (a stop ramp has no reference) becomes null
        "channels": {
            name: [x if math.isfinite(x) else None for x in cols[i].tolist()]
            for i, name in enumerate(NAMES)
        },
    }
    return json.dumps(body, separators=(",", ":")).encode()


@router.get(
    "/{session_id}/telemetry.csv", summary="Full-rate telemetry as CSV (units in the header)",
    response_class=StreamingResponse,
)  # fmt: skip
async def telemetry_csv(
    session_id: Id,
    store: StoreDep,
    _: Viewer,
    start: Annotated[float | None, Query(ge=0, allow_inf_nan=False)] = None,
    end: Annotated[float | None, Query(ge=0, allow_inf_nan=False)] = None,
) -> StreamingResponse:
    await asyncio.to_thread(store.sessions.get, session_id)  # 404 before streaming starts
    pieces = store.telemetry.export_csv(session_id, start=start, end=end)
    return StreamingResponse(
        pieces,  # a sync iterator: Starlette runs it in a thread pool
        media_type="text/csv",
        headers={"Content-Disposition": f'attachment; filename="session-{session_id}.csv"'},
    )
