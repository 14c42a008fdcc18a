"""A reset pressed the moment the machine reads e-stopped clears the latch (CI, 2026-12-01:
``POST /api/v1/machine/reset`` answered 409 "session N is running" right after
``GET /api/v1/machine`` had said ``estopped``).

The worker reports its state as soon as the e-stop's events reach the web process; the pump
records the session's end a moment later. A trainer who sees "e-stopped" and presses reset in
that moment must get the reset (the worker has already ended the session: the reset waits
for its end to be stored), not a refusal to stop a session that no longer runs.

Deterministic: the test holds the web process's event loop (a plain ``time.sleep``) from the
e-stop until the machine reads e-stopped, so the pump cannot record the end before the reset
is asked for. Against the real service on a real worker and a real SQLite file.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

from fastapi import FastAPI

from server.app import create_app
from server.runtime import Runtime
from server.service.machine import BusyError
from server.settings import Settings
from sessions.requests import SessionStart


def test_a_reset_the_moment_the_machine_reads_estopped_clears_the_latch(
    tmp_path: Path,
) -> None:
    url = f"sqlite:///{tmp_path / 'db.sqlite3'}"
    settings = Settings(database_url=url, machine="sim", dashboard=False)
    app: FastAPI = create_app(settings)

    async def scenario() -> None:
        async with app.router.lifespan_context(app):
            runtime: Runtime = app.state.runtime
            machine, store = runtime.machine, runtime.store
            user = await asyncio.to_thread(store.users.create, "Reset")
            record = await machine.start(SessionStart(user_id=user.id, duration=60.0), None)
            await asyncio.sleep(1.0)
            machine.estop()
            deadline = time.monotonic() + 10.0
            while machine.status().state != "estopped":  # the loop held: the pump cannot run
                assert time.monotonic() < deadline, machine.status()
                time.sleep(0.005)
            time.sleep(0.2)  # (the session's end has reached the web process by now, unrecorded)
            assert machine.active is not None  # the race the CI run hit, reproduced
            try:
                await machine.reset()
            except BusyError as exc:
                raise AssertionError(f"a reset after an e-stop was refused: {exc}") from None
            deadline = time.monotonic() + 5.0  # (the worker answers the reset on its own time)
            while (status := machine.status()).state != "idle":
                assert time.monotonic() < deadline, status
                await asyncio.sleep(0.05)
            assert status.session_id is None and not status.armed, status
            stored = await asyncio.to_thread(store.sessions.get, record.id)
            assert stored.status == "stopped" and stored.abort_reason == "e-stop", stored

    asyncio.run(scenario())
