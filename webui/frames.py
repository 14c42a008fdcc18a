"""What a browser may tell viser, checked twice (issue 12.3).

viser applies a client's ``GuiUpdateMessage`` by ``setattr`` on the element's state for
*every* key it names: ``{"update_cb": []}`` unhooks a button's callbacks, ``{"removed":
true}`` makes it ignore everything after — an E-STOP that does nothing until a restart — and
``sync_cb``, ``props`` or ``is_button`` can be overwritten as well. It also accepts any other
message type by name (share links, file uploads, render replies…). A real browser sends only
two kinds of frame: its camera (``ViewerCameraMessage``, on connect and on every resize or
orbit) and ``GuiUpdateMessage`` whose ``updates`` is exactly ``{"value": …}`` (a click, a
number, a pick, text).

1. :func:`admit`, in the proxy, for every browser → viser frame: those two shapes only, each
   field of the right type and finite, one binary msgpack map of at most
   :data:`MAX_FRAME` bytes. Anything else is dropped (and counted) before viser sees it.
2. :func:`guard_updates`, inside viser, on the shared GUI and on each browser's own: an
   update reaches an element only if it changes ``value`` alone, the element is enabled
   and visible, and the value fits it (the type it has, a dropdown's options, a number's
   bounds). This holds for any connection, proxy or not. It replaces one handler of viser's
   (``GuiApi._handle_gui_updates`` on ``GuiApi._websock_interface``: private names of viser
   1.1, checked at start-up and by the tests).
"""

from __future__ import annotations

import logging
import math
from typing import Any

import msgspec
import viser
from viser import _messages

log = logging.getLogger("ergoseek.dashboard")

MAX_FRAME = 64 * 1024  # bytes; a camera or value update is well under 1 KiB
MAX_TEXT = 10_000  # characters of a text input (a user's notes are at most this)
MAX_LIST = 16  # numbers in a vector input
CAMERA = "ViewerCameraMessage"
UPDATE = "GuiUpdateMessage"
CAMERA_SHAPE: dict[str, int | None] = {  # field → length of its vector (None: a number)
    "wxyz": 4,
    "position": 3,
    "look_at": 3,
    "up_direction": 3,
    "fov": None,
    "near": None,
    "far": None,
    "image_height": None,
    "image_width": None,
}


def _number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def _value(v: Any) -> bool:
    if isinstance(v, bool) or _number(v):
        return True
    if isinstance(v, str):
        return len(v) <= MAX_TEXT
    return isinstance(v, list) and len(v) <= MAX_LIST and all(map(_number, v))


def _camera(msg: dict[str, Any]) -> str | None:
    if set(msg) != {"type", *CAMERA_SHAPE}:
        return "camera: unexpected fields"
    for name, n in CAMERA_SHAPE.items():
        v = msg[name]
        ok = _number(v) if n is None else isinstance(v, list) and len(v) == n
        if not ok or (n is not None and not all(map(_number, v))):
            return f"camera: bad {name}"
    return None


def _update(msg: dict[str, Any]) -> str | None:
    if set(msg) != {"type", "uuid", "updates"} or not isinstance(msg["uuid"], str):
        return "gui update: unexpected fields"
    updates = msg["updates"]
    if not isinstance(updates, dict) or list(updates) != ["value"]:
        keys = sorted(updates) if isinstance(updates, dict) else type(updates).__name__
        return f"gui update: only 'value' may change, got {keys}"
    if not _value(updates["value"]):
        return "gui update: bad value"
    return None


def admit(frame: bytes | str | None) -> str | None:
    """Why a browser → viser frame is refused, or None if it may pass unchanged."""
    if not isinstance(frame, bytes):
        return "not a binary frame"
    if len(frame) > MAX_FRAME:
        return "frame too large"
    try:
        msg = msgspec.msgpack.decode(frame)
    except msgspec.DecodeError:
        return "not msgpack"
    if not isinstance(msg, dict):
        return "not a map"
    kind = msg.get("type")
    if kind == CAMERA:
        return _camera(msg)
    if kind == UPDATE:
        return _update(msg)
    return f"type {str(kind)[:40]!r} not allowed"


# -- inside viser ---------------------------------------------------------------------------
def fits(handle: Any, value: Any) -> bool:
    """Whether ``value`` is one the element ``handle`` could send from a browser."""
    if handle.disabled or not handle.visible:
        return False
    current = handle.value
    if isinstance(current, bool):
        return isinstance(value, bool)
    if isinstance(current, int | float):
        if not _number(value):
            return False
        low, high = getattr(handle, "min", None), getattr(handle, "max", None)
        return (low is None or value >= low) and (high is None or value <= high)
    if isinstance(current, str):
        if not isinstance(value, str):
            return False
        options = getattr(handle, "options", None)
        return options is None or value in options
    if isinstance(current, tuple):
        return isinstance(value, list | tuple) and len(value) == len(current)
    return False


def guard_updates(gui: viser.GuiApi) -> None:
    """Let client updates reach ``gui``'s elements only as a browser makes them."""
    iface = gui._websock_interface  # type: ignore[attr-defined]
    original = gui._handle_gui_updates  # type: ignore[attr-defined]
    iface.unregister_handler(_messages.GuiUpdateMessage, original)

    async def guarded(client_id: int, message: _messages.GuiUpdateMessage) -> None:
        handle = gui._gui_input_handle_from_uuid.get(message.uuid)  # type: ignore[attr-defined]
        if handle is None:
            return
        value = message.updates.get("value")
        if list(message.updates) != ["value"] or not fits(handle, value):
            log.warning(
                "dashboard client %s: update %s of %r dropped",
                client_id,
                sorted(message.updates),
                getattr(handle, "label", message.uuid),
            )
            return
        await original(client_id, message)

    iface.register_handler(_messages.GuiUpdateMessage, guarded)
