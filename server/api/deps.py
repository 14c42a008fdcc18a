"""What the routes depend on, as FastAPI dependencies (after full-stack-fastapi-template's
``api/deps.py``): the runtime's parts, and who is asking with which role.

    async def start(body: SessionStart, account: Trainer, machine: MachineDep) -> ...

- ``StoreDep``, ``MachineDep``, ``HubDep``, ``SettingsDep``, ``LimiterDep``: the parts of the
  :class:`server.runtime.Runtime` the lifespan built;
- ``Viewer``, ``Trainer``, ``Admin``: the logged-in account, if its role is at least that
  (roles nest: viewer ⊂ trainer ⊂ admin); 401 without a login, 403 for a weaker role or a
  change made by cookie from another Origin.

The part getters are ``async``: FastAPI would run plain functions on its thread pool, and
nothing may stand between an e-stop request and the machine but the login check.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Annotated

from fastapi import Depends, HTTPException, Request, status
from starlette.requests import HTTPConnection

from server.runtime import Runtime
from server.security import (
    SAFE_METHODS,
    LoginLimiter,
    cookie_write_allowed,
    identify_async,
    unauthorized,
)
from server.service import LiveHub, MachineService
from server.settings import Settings
from sessions.codes import RANK, Role
from sessions.store import AccountRecord, Store


async def get_runtime(conn: HTTPConnection) -> Runtime:
    runtime: Runtime = conn.app.state.runtime
    return runtime


RuntimeDep = Annotated[Runtime, Depends(get_runtime)]


async def get_store(runtime: RuntimeDep) -> Store:
    return runtime.store


async def get_machine(runtime: RuntimeDep) -> MachineService:
    return runtime.machine


async def get_hub(runtime: RuntimeDep) -> LiveHub:
    return runtime.hub


async def get_settings(runtime: RuntimeDep) -> Settings:
    return runtime.settings


async def get_limiter(runtime: RuntimeDep) -> LoginLimiter:
    return runtime.limiter


StoreDep = Annotated[Store, Depends(get_store)]
MachineDep = Annotated[MachineService, Depends(get_machine)]
HubDep = Annotated[LiveHub, Depends(get_hub)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
LimiterDep = Annotated[LoginLimiter, Depends(get_limiter)]


async def current_account(
    request: Request, store: StoreDep, settings: SettingsDep
) -> AccountRecord:
    """The logged-in account; 401 otherwise, 403 for a change by cookie that does not come
    from our own page (an Origin of ours is required: a missing one is refused)."""
    known = getattr(request.state, "identity", None)  # the body guard's, for a request with one
    account, how = known or await identify_async(request, store)
    if account is None:
        raise unauthorized("not logged in" if how == "none" else "login expired or revoked")
    if (
        how == "cookie"
        and request.method not in SAFE_METHODS
        and not cookie_write_allowed(request, settings.allowed_origins)
    ):
        raise HTTPException(status.HTTP_403_FORBIDDEN, detail="cross-site request refused")
    request.state.account = account
    return account


def require(role: Role) -> Callable[[AccountRecord], Awaitable[AccountRecord]]:
    """A dependency: the account, if its role is at least ``role`` (else 403)."""

    async def check(account: Annotated[AccountRecord, Depends(current_account)]) -> AccountRecord:
        if RANK[account.role] < RANK[role]:
            raise HTTPException(
                status.HTTP_403_FORBIDDEN, detail=f"needs the {role} role (you are {account.role})"
            )
        return account

    return check


Viewer = Annotated[AccountRecord, Depends(require("viewer"))]
Trainer = Annotated[AccountRecord, Depends(require("trainer"))]
Admin = Annotated[AccountRecord, Depends(require("admin"))]
