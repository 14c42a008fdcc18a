"""The server outlives its worker, however the worker goes (issue 13.2): the running session
ends ``aborted`` with its data, the machine shows the fault, e-stop and stop answer (the
e-stop never fails; there is no session to stop), reset starts a new worker and the next
session completes.

The worker dies through the simulator's fault injection, eight seconds into every session
(``ERGOSEEK_SIM_FAULT__*``): it aborts on its own (SIGABRT, no goodbye) or exits the way an
unhandled bug makes it exit. A session shorter than that (1 s, then its wind-down to rest and
its 0.5 s stop ramp) is not touched, so the one after the reset completes.
(SIGKILL: tests/api/test_crash.py.)
"""

from __future__ import annotations

from pathlib import Path

import pytest

from testing.server import start_server

pytestmark = pytest.mark.realtime  # timed where it happens: alone, after the parallel rooms

AT = 8.0  # s into a session the worker dies (after the 1 s one, its ~4 s wind-down, its ramp)


@pytest.mark.parametrize(
    ("kind", "words"), [("worker-abort", "worker died"), ("worker-exit", "worker exited")]
)
def test_the_server_recovers_from_its_worker_dying(tmp_path: Path, kind: str, words: str) -> None:
    env = {"ERGOSEEK_SIM_FAULT__KIND": kind, "ERGOSEEK_SIM_FAULT__AT": str(AT)}
    with start_server(tmp_path, env=env) as srv, srv.client("trainer") as c:
        uid = c.post("/api/v1/users", json={"name": "Ray"}).json()["id"]
        sid = c.post("/api/v1/sessions", json={"user_id": uid, "duration": 120}).json()["id"]
        body = srv.wait_status(sid, {"aborted", "completed", "stopped", "faulted"}, 30)
        session = body["session"]
        assert session["status"] == "aborted", session
        assert session["abort_reason"].startswith(words), session["abort_reason"]
        # its data is kept: the eight seconds it ran (every period, none lost)
        tel = c.get(f"/api/v1/sessions/{sid}/telemetry", params={"points": 100_000}).json()
        assert tel["samples"] == round(AT * 1000)
        machine = c.get("/api/v1/machine").json()
        assert machine["state"] == "lost" and machine["fault"] == session["abort_reason"]
        assert c.post("/api/v1/machine/estop").status_code == 202  # never fails
        assert c.post(f"/api/v1/sessions/{sid}/stop").status_code == 409  # not running
        assert c.post("/api/v1/sessions", json={"user_id": uid}).status_code == 409
        assert c.post("/api/v1/machine/reset").status_code == 202  # a new worker
        machine = c.get("/api/v1/machine").json()
        assert machine["state"] == "idle" and machine["fault"] is None
        new = c.post("/api/v1/sessions", json={"user_id": uid, "duration": 1})
        assert new.status_code == 201, new.text
        done = srv.wait_status(new.json()["id"], {"completed", "aborted", "faulted"}, 20)
        assert done["session"]["status"] == "completed"
        # the web process logged no error of its own (the worker's last words are its own)
        assert "ERROR ergoseek" not in srv.log()
