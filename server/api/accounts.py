"""Accounts (admin only): who may log in, with which role."""

from __future__ import annotations

import asyncio

from fastapi import APIRouter, HTTPException, Response

from server.api.deps import Admin, RuntimeDep, StoreDep
from server.api.schemas import AccountIn, AccountPatch, Id
from sessions.store import AccountRecord, Store

router = APIRouter(prefix="/api/v1/accounts", tags=["accounts"])


@router.get("", response_model=list[AccountRecord], summary="Every account")
async def list_accounts(store: StoreDep, _: Admin) -> list[AccountRecord]:
    return await asyncio.to_thread(store.accounts.list)


@router.post("", response_model=AccountRecord, status_code=201, summary="Create an account")
async def create_account(body: AccountIn, store: StoreDep, _: Admin) -> AccountRecord:
    return await asyncio.to_thread(store.accounts.create, body.login, body.password, body.role)


@router.get("/{account_id}", response_model=AccountRecord, summary="One account")
async def get_account(account_id: Id, store: StoreDep, _: Admin) -> AccountRecord:
    return await asyncio.to_thread(store.accounts.get, account_id)


@router.patch(
    "/{account_id}", response_model=AccountRecord, summary="Change role, disable, reset password"
)
async def patch_account(
    account_id: Id, body: AccountPatch, store: StoreDep, runtime: RuntimeDep, _: Admin
) -> AccountRecord:
    record = await asyncio.to_thread(_patch, store, account_id, body)
    for kind, given in (
        ("role", body.role),
        ("disabled", body.disabled),
        ("password", body.password),
    ):
        if given is not None:  # open connections re-check their login now
            runtime.accounts.changed(account_id, kind)  # type: ignore[arg-type]
    return record


def _patch(store: Store, account_id: int, body: AccountPatch) -> AccountRecord:
    with store.transaction():
        record = store.accounts.update(account_id, role=body.role, disabled=body.disabled)
        if body.password is not None:
            store.accounts.set_password(account_id, body.password)
    if body.password is not None or body.disabled:
        store.tokens.revoke_account(account_id)  # logged out everywhere
    return record


@router.delete("/{account_id}", status_code=204, summary="Delete an account (its sessions stay)")
async def delete_account(
    account_id: Id, store: StoreDep, runtime: RuntimeDep, admin: Admin
) -> Response:
    if account_id == admin.id:
        raise HTTPException(409, detail="you cannot delete your own account")
    await asyncio.to_thread(store.accounts.delete, account_id)
    runtime.accounts.changed(account_id, "deleted")
    return Response(status_code=204)
