"""Sessions that end ``aborted`` or ``faulted`` through the server (docs/server.md: "aborted
(velocity limit, …)", "faulted (machine fault)"), started over REST like any other:

- a strong person against a weak controller runs the handle over the request's velocity
  limit: ``aborted``, the reason naming the speed the stored telemetry shows, a ``limit``
  event, a controlled stop that only brakes and ends at zero torque;
- the simulator's velocity sensor reads NaN from session time :data:`AT` on
  (``ERGOSEEK_SIM_FAULT__*``, a broken encoder through the real data path), after the seeker
  has converged: ``faulted``, the machine latched until a reset, the zero-torque fault record
  last in the stored telemetry;
- neither stores a setpoint: the user's stored optimum (set by hand first) is unchanged, though
  the faulted session had converged on an optimum it would otherwise have stored.

- a server whose operator set c² of (5) to 1 mJ (``ERGOSEEK_PASSIVITY_C2``): next to no person
  on the handle and a hard acceleration, the observer's τ̂ runs behind and W(t) dips below −c²:
  ``aborted`` at the breach, the same step as the offline run of the same configuration. (At
  the default 50 J no simulated person breaches it: they never pull.)

Truth: the stored telemetry read back from the store's file, the person's closed-form optimum.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from typing import Any

import httpx
import numpy as np
import pytest

from sessions.store import open_store
from testing.server import ServerProcess, start_server

C2 = 1e-3  # J: the strict server's passivity bound
# next to no person on the handle, a hard acceleration to 5 rad/s (tests/worker/test_safety.py)
PASSIVE_PERSON = {"kind": "linear", "tau0": 0.01, "wmax": 0.5}
PASSIVE = {
    "duration": 3.0,
    "controller": {"kind": "rise", "ks": 0.2},
    "seeker": {"kind": "fixed", "setpoint": 5.0, "bracket": [1, 2, 6], "start_delay": 0.0,
               "filter": {"pole": 30.0}},
}  # fmt: skip
AT = 5.0  # s of session time the velocity sensor starts reading NaN
ENDED = {"completed", "stopped", "aborted", "faulted"}
MANUAL = 2.5  # rad/s: the user's stored optimum, set by hand before the sessions
# A noise-free Hill person and their power's maximiser w* = wmax(√(a² + a) − a).
HILL = {"kind": "hill", "tau0": 3.0, "wmax": 10.0, "curvature": 0.25}
W_STAR = 10.0 * (math.sqrt(0.25**2 + 0.25) - 0.25)  # 3.0902 rad/s
# Brent on a narrow bracket, short windows: converges at ~3 s of session time (offline run).
QUICK = {"kind": "brent", "filter": {"pole": 8.0}, "window": 0.2, "max_window": 0.6,
         "start_delay": 0.2, "bracket": [2.5, 3.1, 3.7], "threshold": 0.3,
         "min_step": 0.1}  # fmt: skip
# A strong person (20 N·m) against a weak RISE controller: over 4 rad/s in ~75 ms.
OVERSPEED = {
    "duration": 3.0,
    "limits": {"max_velocity": 4.0},
    "controller": {"kind": "rise", "ks": 0.1, "beta": 0.01, "alpha_r": 0.1},
    "seeker": {"kind": "fixed", "setpoint": 2.0, "bracket": [1, 2, 3], "start_delay": 0.0},
}


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    env = {"ERGOSEEK_SIM_FAULT__KIND": "nan-velocity", "ERGOSEEK_SIM_FAULT__AT": str(AT)}
    with start_server(tmp_path_factory.mktemp("ends"), env=env) as srv:
        yield srv


@pytest.fixture(scope="module")
def strict(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    """A server whose operator lowered c² of (5) to 1 mJ."""
    env = {"ERGOSEEK_PASSIVITY_C2": str(C2)}
    with start_server(tmp_path_factory.mktemp("strict"), env=env) as srv:
        yield srv


def stored(srv: ServerProcess, sid: int) -> dict[str, np.ndarray]:
    names = ("t", "w", "wd", "u")
    with open_store(srv.database_url, upgrade=False) as store:
        return store.telemetry.columns(sid, names)


def user_with_optimum(c: httpx.Client, name: str, profile: dict[str, Any]) -> int:
    uid = int(c.post("/api/v1/users", json={"name": name, "sim_profile": profile}).json()["id"])
    r = c.post(f"/api/v1/users/{uid}/setpoints", json={"velocity": MANUAL})
    assert r.status_code in (200, 201), r.text
    return uid


def optimum_of(c: httpx.Client, uid: int) -> tuple[float | None, int]:
    sp = c.get(f"/api/v1/users/{uid}/setpoints").json()
    current = sp["current"]["velocity"] if sp["current"] else None
    return current, len(sp["history"])


def run_to_end(
    srv: ServerProcess,
    c: httpx.Client,
    name: str,
    profile: dict[str, Any],
    request: dict[str, Any],
    timeout: float,
) -> tuple[int, tuple[float | None, int], int, dict[str, Any]]:
    """A user with a hand-set optimum, one session of theirs started over REST and waited
    to its end: (user id, their optimum before, session id, the ended session's body)."""
    uid = user_with_optimum(c, name, profile)
    before = optimum_of(c, uid)
    r = c.post("/api/v1/sessions", json={"user_id": uid, **request})
    assert r.status_code == 201, r.text
    sid = int(r.json()["id"])
    return uid, before, sid, srv.wait_status(sid, ENDED, timeout)


def test_the_velocity_limit_ends_the_session_aborted_at_zero_torque(
    server: ServerProcess,
) -> None:
    with server.client("trainer") as c:
        strong = {"kind": "hill", "tau0": 20.0, "wmax": 12.0}
        uid, before, sid, body = run_to_end(server, c, "Strong", strong, OVERSPEED, 20.0)
        session = body["session"]
        assert session["status"] == "aborted", session
        reason = session["abort_reason"]
        m = re.fullmatch(r"velocity over the limit: \|w\| = ([\d.]+) > 4 rad/s", reason)
        assert m, reason
        events = c.get(f"/api/v1/sessions/{sid}/events").json()
        assert events == body["events"]
        limits = [e for e in events if e["kind"] == "limit"]
        assert limits and limits[0]["detail"]["limit"] == "velocity", events
        assert optimum_of(c, uid) == before  # no setpoint from an aborted session
        assert c.get("/api/v1/machine").json()["state"] == "idle"  # nothing latched
    d = stored(server, sid)
    w, u = d["w"], d["u"]
    stop = np.isnan(d["wd"])  # the controlled stop's rows (no reference: the ramp's torque)
    over = np.flatnonzero(np.abs(w) > 4.0)
    assert len(over) > 0, "the stored telemetry never went over the limit"
    assert float(m.group(1)) == pytest.approx(abs(w[over[0]]), abs=0.006)  # the speed it saw
    assert d["t"][over[0]] < 0.5  # over the limit early: the session did not run its 3 s
    assert stop.any() and np.all(u[stop] * w[stop] <= 0.0)  # the stop brakes, never drives
    assert stop[over[0] + 1 :].all() and not stop[: over[0] + 1].any()  # stopped at once
    assert u[-1] == 0.0 and stop[-1]  # the stop's last record: zero torque


def test_a_machine_fault_ends_the_session_faulted_and_stores_no_setpoint(
    server: ServerProcess,
) -> None:
    with server.client("trainer") as c:
        request = {"duration": 30.0, "seed": 1, "seeker": QUICK}
        uid, before, sid, body = run_to_end(server, c, "Hill", HILL, request, 30.0)
        session = body["session"]
        assert session["status"] == "faulted", session
        assert session["abort_reason"] == "non-finite measured velocity w = nan"
        # it had found the person's optimum: a completed session would have stored it
        assert session["converged"] and session["optimum_w"] == pytest.approx(W_STAR, abs=0.15)
        assert session["duration"] == pytest.approx(AT, abs=0.002)
        kinds = [e["kind"] for e in c.get(f"/api/v1/sessions/{sid}/events").json()]
        assert "fault" in kinds, kinds
        assert optimum_of(c, uid) == before  # no setpoint from a faulted session
        machine = c.get("/api/v1/machine").json()
        assert machine["state"] == "faulted" and "velocity w = nan" in machine["fault"]
        assert c.post("/api/v1/sessions", json={"user_id": uid}).status_code == 409  # latched
        assert c.post("/api/v1/machine/reset").status_code == 202
        assert c.get("/api/v1/machine").json()["state"] == "idle"
        assert c.get("/api/v1/machine").json()["session_id"] is None  # the reset started nothing
    d = stored(server, sid)
    t, u = d["t"], d["u"]
    assert len(t) == round(AT * 1000) + 1  # every period before the fault, then its record
    assert np.count_nonzero(u[-200:-1]) > 150  # it was pushing until then
    assert u[-1] == 0.0  # the fault's zero-torque record, last
    assert np.isfinite(d["w"][:-1]).all()  # the NaN was never stored as a velocity


def test_a_passivity_breach_ends_the_session_aborted_where_the_offline_run_breaches(
    strict: ServerProcess,
) -> None:
    with strict.client("trainer") as c:
        request = {"seed": 3, **PASSIVE}
        uid, before, sid, body = run_to_end(
            strict, c, "Barely there", PASSIVE_PERSON, request, 20.0
        )
        session = body["session"]
        assert session["status"] == "aborted", session
        assert session["abort_reason"].startswith("passivity breached: W = ")
        assert session["abort_reason"].endswith(f"< -c² = {-C2:g} J")
        limits = [e for e in body["events"] if e["kind"] == "limit"]
        assert limits and limits[0]["detail"]["limit"] == "passivity", body["events"]
        assert optimum_of(c, uid) == before  # no setpoint from an aborted session
        config = c.get(f"/api/v1/sessions/{sid}").json()["session"]["config"]
    # the same configuration offline: W(t) crosses -c² on the step the live session stopped
    from sessions.config import SessionConfig
    from sessions.simulation import run_simulation

    ref = run_simulation(SessionConfig.model_validate(config))
    breach = int(np.argmax(ref.column("W") < -C2))
    assert breach > 0
    d = stored(strict, sid)
    stop = np.isnan(d["wd"])
    assert stop.any() and not stop[: breach + 1].any() and stop[breach + 1 :].all()
    assert np.all(d["u"][stop] * d["w"][stop] <= 0.0)  # the stop brakes, never drives
    assert d["u"][-1] == 0.0
