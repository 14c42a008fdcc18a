"""Protocol templates: named protocols, private to a trainer or shared (``/api/v1/protocols``).

Viewers read the shared templates; trainers create templates, edit and delete their own and
the shared ones; administrators any (the rules: :mod:`sessions.store.templates`). A template
one may not read answers 404. Everything is SI (rad/s, s)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Annotated, TypeVar

from fastapi import APIRouter, HTTPException, Query, Response

from server.api.deps import MachineDep, StoreDep, Trainer, Viewer
from server.api.schemas import Id
from server.api.workflow_schemas import (
    PhasePreview,
    PreviewIn,
    PreviewOut,
    TemplateIn,
    TemplatePatch,
)
from server.service.machine import MachineService
from sessions.protocol.config import describe, phase_longest
from sessions.requests import SessionStart, session_config
from sessions.store import AccountRecord, ForbiddenError, Store, TemplateRecord

router = APIRouter(prefix="/api/v1/protocols", tags=["protocols"])
T = TypeVar("T")


async def _run(fn: Callable[[], T]) -> T:
    """The store call in a thread; a refusal by the template rules is 403."""
    try:
        return await asyncio.to_thread(fn)
    except ForbiddenError as exc:
        raise HTTPException(403, detail=str(exc)) from None


@router.get("", response_model=list[TemplateRecord], summary="Templates you may read, by name")
async def list_templates(
    store: StoreDep,
    account: Viewer,
    search: Annotated[str | None, Query(max_length=100)] = None,
) -> list[TemplateRecord]:
    return await _run(
        lambda: store.templates.list(account_id=account.id, role=account.role, search=search)
    )


@router.post("", response_model=TemplateRecord, status_code=201, summary="Save a template")
async def create_template(body: TemplateIn, store: StoreDep, account: Trainer) -> TemplateRecord:
    return await _run(
        lambda: store.templates.create(
            account.id, body.name, body.protocol, description=body.description, shared=body.shared
        )
    )


@router.post(
    "/preview", response_model=PreviewOut,
    summary="Check a protocol against a user's next session: its phases and duration",
)  # fmt: skip
async def preview(body: PreviewIn, store: StoreDep, machine: MachineDep, _: Viewer) -> PreviewOut:
    return await _run(lambda: _preview(store, machine, body))


def _preview(store: Store, machine: MachineService, body: PreviewIn) -> PreviewOut:
    sim_profile, optimum = None, None
    if body.user_id is not None:
        user = store.users.get(body.user_id)
        current = store.setpoints.current(body.user_id)
        sim_profile, optimum = user.sim_profile, current.velocity if current else None
    req = SessionStart(user_id=body.user_id or 1, protocol=body.protocol, seeker=body.seeker)
    cfg = session_config(req, machine.rig, sim_profile=sim_profile, optimum=optimum)
    lo, _, hi = cfg.seeker.bracket
    phases = [
        PhasePreview(index=i, kind=ph.kind, name=ph.name or f"{ph.kind} {i + 1}",
                     longest=phase_longest(ph, (lo, hi), cfg.machine.max_velocity))
        for i, ph in enumerate(body.protocol.phases)
    ]  # fmt: skip
    return PreviewOut(
        summary=describe(body.protocol), duration=cfg.duration, bracket=cfg.seeker.bracket,
        phases=phases,
    )  # fmt: skip


@router.get("/{template_id}", response_model=TemplateRecord, summary="One template")
async def get_template(template_id: Id, store: StoreDep, account: Viewer) -> TemplateRecord:
    return await _run(
        lambda: store.templates.get(template_id, account_id=account.id, role=account.role)
    )


@router.patch("/{template_id}", response_model=TemplateRecord, summary="Edit a template")
async def patch_template(
    template_id: Id, body: TemplatePatch, store: StoreDep, account: Trainer
) -> TemplateRecord:
    return await _run(lambda: _patch(store, template_id, body, account))


def _patch(
    store: Store, template_id: int, body: TemplatePatch, account: AccountRecord
) -> TemplateRecord:
    return store.templates.update(
        template_id, account_id=account.id, role=account.role, name=body.name,
        description=body.description, shared=body.shared, protocol=body.protocol,
    )  # fmt: skip


@router.delete("/{template_id}", status_code=204, summary="Delete a template")
async def delete_template(template_id: Id, store: StoreDep, account: Trainer) -> Response:
    await _run(
        lambda: store.templates.delete(template_id, account_id=account.id, role=account.role)
    )
    return Response(status_code=204)
