"""A session's files for other tools: the one-page PDF report and the FIT activity.

Role-checked like the telemetry (viewers and up). Built off the event loop (a thread; at most
:data:`PARALLEL` at once, so exports cannot crowd out the machine's requests) and streamed.
404 for an unknown session, 409 while it runs (or without telemetry), 422 for a bad query."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from typing import Annotated
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from fastapi import APIRouter, HTTPException, Query
from fastapi.responses import StreamingResponse

from server.api.deps import StoreDep, Viewer
from server.api.schemas import Id
from server.service.exports import activity_fit, report_pdf
from sessions.units import VelocityUnit

router = APIRouter(prefix="/api/v1/sessions", tags=["exports"])
PARALLEL = 2
PIECE = 64 * 1024
_slots: dict[int, asyncio.Semaphore] = {}  # per event loop (the tests run several)


def _slot() -> asyncio.Semaphore:
    """Exports wait here, not in the thread pool (whose threads the logins need)."""
    return _slots.setdefault(id(asyncio.get_running_loop()), asyncio.Semaphore(PARALLEL))


ERRORS = {
    404: {"description": "no such session"},
    409: {"description": "the session is running, or has no telemetry"},
}


def _pieces(data: bytes) -> Iterator[bytes]:
    for i in range(0, len(data), PIECE):
        yield data[i : i + PIECE]


def _attachment(data: bytes, media: str, filename: str) -> StreamingResponse:
    return StreamingResponse(
        _pieces(data), media_type=media,
        headers={"Content-Disposition": f'attachment; filename="{filename}"',
                 "Content-Length": str(len(data))},
    )  # fmt: skip


def _zone(name: str | None) -> ZoneInfo | None:
    if name is None:
        return None
    try:
        return ZoneInfo(name)
    except (ZoneInfoNotFoundError, ValueError):
        raise HTTPException(
            422, detail=[{"loc": ["query", "tz"], "msg": f"unknown time zone {name!r}",
                          "type": "value_error"}],
        ) from None  # fmt: skip


@router.get(
    "/{session_id}/report.pdf", response_class=StreamingResponse, responses=ERRORS,
    summary="The session's one-page report (PDF): user, protocol, optimum, powers, charts",
)  # fmt: skip
async def report(
    session_id: Id,
    store: StoreDep,
    account: Viewer,
    velocity_unit: Annotated[
        VelocityUnit | None, Query(description="default: your preference (rpm)")
    ] = None,
    tz: Annotated[
        str | None, Query(max_length=64, description="IANA time zone for the date (default UTC)")
    ] = None,
) -> StreamingResponse:
    zone = _zone(tz)
    async with _slot():
        unit = (
            velocity_unit
            or (await asyncio.to_thread(store.preferences.get, account.id)).velocity_unit
        )
        data = await asyncio.to_thread(
            report_pdf, store, session_id, velocity_unit=unit, timezone=zone
        )
    return _attachment(data, "application/pdf", f"session-{session_id}.pdf")


@router.get(
    "/{session_id}/activity.fit", response_class=StreamingResponse, responses=ERRORS,
    summary="The session as a FIT activity: records of power and cadence, a lap per phase",
)  # fmt: skip
async def activity(
    session_id: Id,
    store: StoreDep,
    _: Viewer,
    interval: Annotated[
        int, Query(ge=1, le=3600, description="s between records (FIT stamps whole seconds)")
    ] = 1,
) -> StreamingResponse:
    async with _slot():
        data = await asyncio.to_thread(activity_fit, store, session_id, record_interval=interval)
    return _attachment(data, "application/vnd.ant.fit", f"session-{session_id}.fit")
