"""What the proxy lets a browser tell viser (:func:`webui.frames.admit`): what a real browser
sends — its camera and value updates, as viser's client encodes them (``msgpack`` maps,
checked here against ``msgspec`` and viser's own message classes) — and nothing else."""

from __future__ import annotations

import math

import msgspec
import pytest
from viser import _messages

from testing.viser_wire import CAMERA, encode, gui_update
from webui.frames import MAX_FRAME, MAX_TEXT, admit

UUID = "0fc00b5e-8d0c-4d6e-9a53-3f0d4b1d2c11"


@pytest.mark.parametrize(
    "frame",
    [
        encode(CAMERA),
        gui_update(UUID, value=True),  # a click
        gui_update(UUID, value=3600.0),
        gui_update(UUID, value=7),
        gui_update(UUID, value="Ada (#1)"),
        gui_update(UUID, value="x" * MAX_TEXT),
        gui_update(UUID, value=[0.1, 0.2, 0.3]),
    ],
)
def test_what_a_browser_sends_passes(frame: bytes) -> None:
    assert admit(frame) is None
    message = _messages.Message.deserialize(frame)  # viser reads it as the browser meant
    assert type(message).__name__ in ("ViewerCameraMessage", "GuiUpdateMessage")


@pytest.mark.parametrize(
    ("frame", "why"),
    [
        (gui_update(UUID, update_cb=[]), "only 'value'"),
        (gui_update(UUID, removed=True), "only 'value'"),
        (gui_update(UUID, sync_cb=None), "only 'value'"),
        (gui_update(UUID, props={"label": "x"}), "only 'value'"),
        (gui_update(UUID, is_button=False), "only 'value'"),
        (gui_update(UUID, value=True, update_cb=[]), "only 'value'"),
        (gui_update(UUID), "only 'value'"),
        (gui_update(UUID, value=math.nan), "bad value"),
        (gui_update(UUID, value=math.inf), "bad value"),
        (gui_update(UUID, value="x" * (MAX_TEXT + 1)), "bad value"),
        (gui_update(UUID, value={"nested": 1}), "bad value"),
        (gui_update(UUID, value=[1.0] * 17), "bad value"),
        (encode({"type": "GuiUpdateMessage", "uuid": UUID, "updates": [1]}), "only 'value'"),
        (encode({"type": "GuiUpdateMessage", "uuid": 5, "updates": {"value": 1}}), "fields"),
        (encode({"type": "GuiUpdateMessage", "uuid": UUID, "updates": {"value": 1}, "x": 1}),
         "fields"),
        (encode({"type": "ShareUrlRequest"}), "not allowed"),
        (encode({"type": "GuiButtonHoldMessage", "uuid": UUID, "phase": "start"}), "not allowed"),
        (encode({"type": "FileTransferStartUpload", "transfer_uuid": "t"}), "not allowed"),
        (encode({"type": "GuiFormSubmitMessage", "uuid": UUID}), "not allowed"),
        (encode({"type": "ScenePointerMessage"}), "not allowed"),
        (encode({**CAMERA, "fov": math.nan}), "camera"),
        (encode({**CAMERA, "wxyz": [1.0, 0.0, 0.0]}), "camera"),
        (encode({**CAMERA, "extra": 1}), "camera"),
        (encode({**CAMERA, "image_width": True}), "camera"),
        (encode([1, 2, 3]), "not a map"),
        (b"\xc1\xff", "not msgpack"),
        (encode({"type": "GuiUpdateMessage", "uuid": UUID, "updates": {"value": "y" * MAX_FRAME}}),
         "too large"),
    ],
)  # fmt: skip
def test_anything_else_is_refused(frame: bytes, why: str) -> None:
    reason = admit(frame)
    assert reason is not None and why in reason, reason


def test_text_frames_and_nothing_are_refused() -> None:
    assert admit(msgspec.json.encode(CAMERA).decode()) == "not a binary frame"
    assert admit(None) == "not a binary frame"


def test_a_browser_sends_no_faster_than_a_browser_does() -> None:
    from sessions.store import AccountRecord
    from webui.proxy import FRAME_BURST, FRAME_RATE, Connection

    account = AccountRecord.model_construct(id=1, login="x", role="trainer", disabled=False)
    conn = Connection(account, refilled=0.0)
    passed = sum(conn.spend(0.0) for _ in range(int(FRAME_BURST) + 50))
    assert passed == FRAME_BURST  # a burst, then nothing
    passed = sum(conn.spend(0.5) for _ in range(int(FRAME_BURST)))
    assert passed == FRAME_RATE * 0.5  # refilled at the rate
    assert conn.spend(0.5 + 1 / FRAME_RATE)  # one more after one frame's time
