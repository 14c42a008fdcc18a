"""SIGTERM while a session runs and a live client watches (issue 12.6): the client receives
the session's zero-torque record and its end before its connection is closed, and the stored
session says the server was shut down by SIGTERM, not that an operator stopped it."""

from __future__ import annotations

import contextlib
import json
import signal
import threading
import time
from pathlib import Path
from typing import Any

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from sessions.store import open_store
from testing.server import start_server


def test_sigterm_shows_live_clients_the_zero_torque_record_first(tmp_path: Path) -> None:
    srv = start_server(tmp_path)
    frames: list[dict[str, Any]] = []
    try:
        with srv.client("trainer") as c:
            uid = c.post("/api/v1/users", json={"name": "Term"}).json()["id"]
            sid = c.post("/api/v1/sessions", json={"user_id": uid, "duration": 60}).json()["id"]
        ws = connect(f"{srv.ws_url}/api/v1/live?rate=30", additional_headers=srv.headers("viewer"))
        first = threading.Event()

        def read() -> None:
            with contextlib.suppress(ConnectionClosed):
                for msg in ws:
                    frames.append(json.loads(msg))
                    if frames[-1]["type"] == "telemetry":
                        first.set()

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        assert first.wait(15), "no telemetry before the signal"
        time.sleep(0.5)
        srv.proc.send_signal(signal.SIGTERM)  # type: ignore[union-attr]
        reader.join(30)
        assert not reader.is_alive()
    finally:
        srv.stop()
    kinds = [f["type"] for f in frames]
    assert "session_finished" in kinds, kinds[-5:]
    end_at = kinds.index("session_finished")
    telemetry = [f for f in frames[:end_at] if f["type"] == "telemetry"]
    assert telemetry and telemetry[0]["session_id"] == sid
    assert telemetry[-1]["u_out"][-1] == 0.0, telemetry[-1]  # the record that zeroed it
    end = frames[end_at]
    assert end["session_id"] == sid and end["status"] == "stopped"
    with open_store(srv.database_url) as store:
        s = store.sessions.get(sid)
    assert s.status == "stopped"
    assert "SIGTERM" in (s.abort_reason or "") and "operator" not in (s.abort_reason or "")
