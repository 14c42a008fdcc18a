"""``/api/v1/live``: telemetry at a requested rate, events and seeker progress, over a
WebSocket. Authenticated by bearer token (``Authorization`` header) or the login cookie;
a browser's Origin must be the server's own. Query: ``rate`` samples per second (default 30,
up to the loop rate). Frames are JSON text (see :mod:`server.service.live`)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import math

from fastapi import APIRouter, WebSocket, WebSocketDisconnect, status

from server.api.deps import RuntimeDep
from server.runtime import Runtime
from server.security import identify, origin_allowed
from server.service import serve_subscription
from sessions.store import AccountRecord

router = APIRouter(tags=["live"])


async def _admitted(ws: WebSocket, runtime: Runtime, rate: float) -> AccountRecord | None:
    """The account, if the socket may open: a login, our Origin, a cookie only with an Origin,
    a positive finite rate."""
    account, how = await asyncio.to_thread(identify, ws, runtime.store)
    origin = ws.headers.get("origin")
    refused = (
        account is None
        or not origin_allowed(ws, runtime.settings.allowed_origins)
        or (how == "cookie" and origin is None)
        or not math.isfinite(rate)
        or rate <= 0
    )
    return None if refused else account


@router.websocket("/api/v1/live")
async def live(ws: WebSocket, runtime: RuntimeDep, rate: float = 30.0) -> None:
    account = await _admitted(ws, runtime, rate)
    if account is None:
        await ws.close(code=status.WS_1008_POLICY_VIOLATION)
        return
    await ws.accept()
    hub = runtime.hub
    sub = hub.subscribe(rate)
    hello = {"type": "hello", "account": account.login, "rate": sub.rate}
    active = runtime.machine.active_session()  # a client joining mid-session: where it stands
    hello["stage"] = active.stage.to_dict() if active and active.stage else None
    await ws.send_json({**hello, "machine": runtime.machine.status().model_dump()})

    async def send(frame: dict[str, object]) -> None:
        await ws.send_text(json.dumps(frame, separators=(",", ":"), allow_nan=False))

    sender = asyncio.create_task(serve_subscription(hub, sub, send))
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
        hub.unsubscribe(sub)
