"""``/api/v1/live``: telemetry at a requested rate, events and seeker progress, over a
WebSocket. Authenticated by bearer token (``Authorization`` header) or the login cookie;
a browser's Origin must be the server's own. Query: ``rate`` samples per second (default 30,
up to the loop rate). Frames are JSON text (see :mod:`server.service.live`).

Connections are capped per account and in all (``live_max_per_account``,
``live_max_total``): past a cap the handshake is answered 429. An open connection's login is
checked again the moment its account changes (role, disabled, password, deleted, logged
out: :class:`server.service.accounts.AccountEvents`) and every :data:`RECHECK_S` seconds
(expiry, changes made by another process); a connection whose login has ended is closed
(1008)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import math

from fastapi import APIRouter, WebSocket, WebSocketDisconnect, status
from fastapi.responses import JSONResponse

from server.api.deps import RuntimeDep
from server.runtime import Runtime
from server.security import identify_async, origin_allowed
from server.service import serve_subscription
from server.service.accounts import AccountChange
from sessions.store import AccountRecord

router = APIRouter(tags=["live"])

RECHECK_S = 30.0  # s between checks of an open connection's login, changes or not


async def _admitted(ws: WebSocket, runtime: Runtime, rate: float) -> AccountRecord | None:
    """The account, if the socket may open: a login, our Origin, a cookie only with an Origin,
    a positive finite rate."""
    account, how = await identify_async(ws, runtime.store)
    origin = ws.headers.get("origin")
    refused = (
        account is None
        or not origin_allowed(ws, runtime.settings.allowed_origins)
        or (how == "cookie" and origin is None)
        or not math.isfinite(rate)
        or rate <= 0
    )
    return None if refused else account


async def _watch_login(ws: WebSocket, runtime: Runtime, account: AccountRecord) -> None:
    """Close ``ws`` once its login ends: checked when the account changes, and every
    RECHECK_S seconds."""
    changed = asyncio.Event()

    def on_change(change: AccountChange) -> None:
        if change.account_id == account.id:
            changed.set()

    unsubscribe = runtime.accounts.subscribe(on_change)
    try:
        while True:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(changed.wait(), RECHECK_S)
            changed.clear()
            now, _ = await identify_async(ws, runtime.store)
            if now is None or now.id != account.id:
                with contextlib.suppress(RuntimeError):
                    await ws.close(code=status.WS_1008_POLICY_VIOLATION, reason="login ended")
                return
    finally:
        unsubscribe()


@router.websocket("/api/v1/live")
async def live(ws: WebSocket, runtime: RuntimeDep, rate: float = 30.0) -> None:
    account = await _admitted(ws, runtime, rate)
    if account is None:
        await ws.close(code=status.WS_1008_POLICY_VIOLATION)
        return
    refusal = runtime.live_gate.enter(account.id)
    if refusal is not None:
        await ws.send_denial_response(JSONResponse({"detail": refusal}, status_code=429))
        return
    try:
        await ws.accept()
        await _serve(ws, runtime, account, rate)
    finally:
        runtime.live_gate.leave(account.id)


async def _serve(ws: WebSocket, runtime: Runtime, account: AccountRecord, rate: float) -> None:
    hub = runtime.hub
    sub = hub.subscribe(rate)
    hello = {"type": "hello", "account": account.login, "rate": sub.rate}
    active = runtime.machine.active_session()  # a client joining mid-session: where it stands
    hello["stage"] = active.stage.to_dict() if active and active.stage else None
    await ws.send_json({**hello, "machine": runtime.machine.status().model_dump()})

    async def send(frame: dict[str, object]) -> None:
        await ws.send_text(json.dumps(frame, separators=(",", ":"), allow_nan=False))

    sender = asyncio.create_task(serve_subscription(hub, sub, send))
    watcher = asyncio.create_task(_watch_login(ws, runtime, account))
    try:
        while True:  # the client may change its rate: {"rate": 100}
            msg = await ws.receive_text()
            with contextlib.suppress(ValueError, TypeError, KeyError):
                new = float(json.loads(msg)["rate"])
                if new > 0:
                    hub.unsubscribe(sub)
                    sender.cancel()
                    sub = hub.subscribe(new)
                    sender = asyncio.create_task(serve_subscription(hub, sub, send))
    except (WebSocketDisconnect, RuntimeError):
        pass
    finally:
        sender.cancel()
        watcher.cancel()
        hub.unsubscribe(sub)
