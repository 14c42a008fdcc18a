"""A command given the moment the machine reads that a session has ended is not refused for
that session (CI, 2026-12-01: ``POST /api/v1/machine/reset`` answered 409 "session N is
running" right after ``GET /api/v1/machine`` had said ``estopped``).

The worker's state is read as soon as its events reach the web process; the pump records the
session's end a moment later. A trainer who sees "e-stopped" and presses reset, or sees "idle"
and starts the next session, in that moment gets what they asked for: the command waits
(bounded) for the end to be stored, not a refusal over a session that no longer runs.

Deterministic: the test holds the web process's event loop (a plain ``time.sleep``) from the
e-stop or the stop until the machine reads its end, so the pump cannot record that end before
the command is given. Against the real service on a real worker and a real SQLite file.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import pytest
from fastapi import FastAPI

from server.app import create_app
from server.runtime import Runtime
from server.service.machine import BusyError, MachineService
from server.settings import Settings
from sessions.requests import SessionStart


def _hold_until(machine: MachineService, state: str) -> None:
    """Block the event loop until the machine reads ``state`` (the pump cannot run)."""
    deadline = time.monotonic() + 10.0
    while machine.status().state != state:
        assert time.monotonic() < deadline, machine.status()
        time.sleep(0.005)
    time.sleep(0.2)  # (the session's end has reached the web process by now, unrecorded)
    assert machine.active is not None  # the race the CI run hit, reproduced


async def _until_idle(machine: MachineService) -> None:
    deadline = time.monotonic() + 5.0  # (the worker answers a reset on its own time)
    while (status := machine.status()).state != "idle":
        assert time.monotonic() < deadline, status
        await asyncio.sleep(0.05)


@pytest.mark.parametrize("ending", ["estop-then-reset", "stop-then-start"])
def test_a_command_the_moment_a_session_reads_ended_is_not_refused(
    tmp_path: Path, ending: str
) -> None:
    url = f"sqlite:///{tmp_path / 'db.sqlite3'}"
    app: FastAPI = create_app(Settings(database_url=url, machine="sim", dashboard=False))

    async def scenario() -> None:
        async with app.router.lifespan_context(app):
            runtime: Runtime = app.state.runtime
            machine, store = runtime.machine, runtime.store
            user = await asyncio.to_thread(store.users.create, "Reset")
            first = await machine.start(SessionStart(user_id=user.id, duration=60.0), None)
            await asyncio.sleep(1.0)
            try:
                if ending == "estop-then-reset":
                    machine.estop()
                    _hold_until(machine, "estopped")
                    await machine.reset()
                    await _until_idle(machine)
                else:
                    machine.worker.stop(immediate=True)  # (the service's stop, at once)
                    _hold_until(machine, "idle")
                    second = await machine.start(SessionStart(user_id=user.id, duration=60), None)
                    assert machine.active is not None and machine.active.db_id == second.id
                    await machine.halt()
            except BusyError as exc:
                raise AssertionError(f"refused after the session had ended: {exc}") from None
            status = machine.status()
            assert status.session_id is None and not status.armed, status
            stored = await asyncio.to_thread(store.sessions.get, first.id)
            reason = "e-stop" if ending == "estop-then-reset" else "stopped at once by the operator"
            assert stored.status == "stopped" and stored.abort_reason == reason, stored

    asyncio.run(scenario())
