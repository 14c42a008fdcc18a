"""Gains the loop cannot hold are refused at the REST door (issue 13.1): 422 naming the field,
with the bound in the reason, and nothing stored; the same request inside the bound starts."""

from __future__ import annotations

import pytest

from testing.server import ServerProcess, start_server

HILL = {"kind": "hill", "tau0": 3.0, "wmax": 10.0, "curvature": 0.25}


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> ServerProcess:
    # a 50 Hz loop: the rate the server allows at which ks = 12 chatters at the torque limit
    with start_server(tmp_path_factory.mktemp("srv"), env={"ERGOSEEK_RATE": "50"}) as srv:
        yield srv


def test_a_gain_beyond_the_bound_is_a_422_naming_the_field(server: ServerProcess) -> None:
    with server.client("trainer") as c:
        user = c.post("/api/v1/users", json={"name": "Bo", "sim_profile": HILL}).json()
        start = {"user_id": user["id"], "duration": 2.0, "controller": {"kind": "rise", "ks": 12}}
        r = c.post("/api/v1/sessions", json=start)
        assert r.status_code == 422, r.text
        (problem,) = r.json()["detail"]
        assert problem["loc"] == ["body", "controller", "ks"]
        assert problem["msg"].startswith("12 is more than the loop can hold at 50 Hz")
        assert "(ks + 1)·dt/J ≤ 2/(2 − αr·dt)" in problem["msg"]
        assert problem["msg"].endswith("i.e. ks ≤ 4.208")
        measured = {**start, "controller": {"kind": "measured", "k": 6.0}}
        r = c.post("/api/v1/sessions", json=measured)
        # the simulated machine has a torque sensor: the bound, not the sensor, refuses it
        assert r.status_code == 422 and r.json()["detail"][0]["loc"][-1] == "k", r.text
        assert "k ≤ 5 N·m·s/rad" in r.json()["detail"][0]["msg"]
        # nothing was stored, the machine is still idle
        assert c.get("/api/v1/sessions", params={"user_id": user["id"]}).json()["total"] == 0
        ok = c.post("/api/v1/sessions", json={**start, "controller": {"kind": "rise", "ks": 4.2}})
        assert ok.status_code == 201, ok.text
        server.wait_status(ok.json()["id"], {"completed", "stopped", "aborted", "faulted"}, 30)
        done = c.get(f"/api/v1/sessions/{ok.json()['id']}").json()["session"]
        assert done["status"] == "completed", done
