"""The trainer's workflow over HTTP against a real server (simulated machine, real SQLite and,
for one session, real PostgreSQL): a protocol session from a template to its stored phases,
ending at rest; the live stream's stages; the exports decoded by independent readers
(fitdecode, pypdf) against the stored telemetry; progress, overlay, preferences."""

from __future__ import annotations

import io
import itertools
import json
import math
import time
from collections.abc import Iterator
from datetime import datetime
from typing import Any

import numpy as np
import pypdf
import pytest
from websockets.sync.client import connect

from sessions.store import open_store
from testing.exports import decode_fit, record_bins
from testing.postgres import postgres
from testing.server import ServerProcess, start_server

RPM = 60.0 / (2.0 * math.pi)  # independent of sessions.units
HILL = {"kind": "hill", "tau0": 3.0, "wmax": 10.0, "curvature": 0.25, "noise": 0.02}
QUICK = {"kind": "brent", "filter": {"pole": 6.0}, "window": 0.3, "max_window": 2.0,
         "start_delay": 0.5}  # fmt: skip
PROTOCOL = {
    "name": "warm, seek, 2 × 10/10, cool",
    "phases": [
        {"kind": "warmup", "duration": 5.0},
        {"kind": "seek", "duration": 60.0, "hold": 1.0},
        {"kind": "train", "intervals": 2, "work": 10.0, "rest": 10.0, "countdown": 2.0},
        {"kind": "cooldown", "duration": 5.0, "hold": 1.0},
    ],
}
ENDED = {"completed", "stopped", "aborted", "faulted"}


def wait_phases(srv: ServerProcess, sid: int, timeout: float = 30.0) -> list[dict[str, Any]]:
    """The session's phases once every one has its summary (the pump writes them last)."""
    deadline = time.monotonic() + timeout
    with srv.client("viewer") as c:
        while True:
            phases = c.get(f"/api/v1/sessions/{sid}/phases").json()
            if all(p["mean_power"] is not None for p in phases) or time.monotonic() > deadline:
                return phases
            time.sleep(0.2)


def stored(srv: ServerProcess, sid: int, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    with open_store(srv.database_url, upgrade=False) as store:
        return store.telemetry.columns(sid, names)


@pytest.fixture(scope="module")
def ran(server: ServerProcess) -> dict[str, Any]:
    """A protocol session from a shared template, followed on the live stream to its end."""
    with server.client("trainer") as c:
        user = c.post("/api/v1/users", json={"name": "Zoë Ødegård", "body_mass_kg": 64.0,
                                             "sim_profile": HILL}).json()  # fmt: skip
        template = c.post("/api/v1/protocols", json={"name": "short", "protocol": PROTOCOL,
                                                     "shared": True}).json()  # fmt: skip
        stages, stage_column, live = [], set(), None
        with connect(f"{server.ws_url}/api/v1/live?rate=20",
                     additional_headers=server.headers("viewer")) as ws:  # fmt: skip
            assert json.loads(ws.recv(timeout=10))["stage"] is None  # nothing running yet
            start = c.post("/api/v1/sessions", json={"user_id": user["id"], "seed": 5,
                                                     "template_id": template["id"],
                                                     "seeker": QUICK})  # fmt: skip
            assert start.status_code == 201, start.text
            sid = start.json()["id"]
            deadline = time.monotonic() + 10  # the pump has seen the first stage
            while c.get(f"/api/v1/sessions/{sid}").json()["live"]["stage"] is None:
                assert time.monotonic() < deadline
                time.sleep(0.05)
            with connect(f"{server.ws_url}/api/v1/live",
                         additional_headers=server.headers("viewer")) as late:  # fmt: skip
                joined = json.loads(late.recv(timeout=10))["stage"]  # joining mid-session
            deadline = time.monotonic() + 150
            while time.monotonic() < deadline:
                frame = json.loads(ws.recv(timeout=20))
                if frame["type"] == "stage" and frame.get("db_session_id") == sid:
                    stages.append(frame["stage"])
                    if frame["stage"]["role"] == "work" and live is None:
                        live = c.get(f"/api/v1/sessions/{sid}").json()["live"]
                elif frame["type"] == "telemetry" and frame["session_id"] == sid:
                    stage_column.update(x for x in frame["stage"] if x is not None)
                elif frame["type"] == "session_finished" and frame["session_id"] == sid:
                    break
    body = server.wait_status(sid, ENDED, 30)
    return {"sid": sid, "user": user, "template": template, "body": body, "stages": stages,
            "stage_column": stage_column, "live": live, "joined": joined,
            "phases": wait_phases(server, sid)}  # fmt: skip


def test_the_protocol_runs_to_rest_and_its_phases_are_stored(
    server: ServerProcess, ran: dict[str, Any]
) -> None:
    s = ran["body"]["session"]
    assert s["status"] == "completed" and s["converged"], s
    assert s["config"]["protocol"]["name"] == PROTOCOL["name"]
    phases = ran["phases"]
    assert [p["kind"] for p in phases] == ["warmup", "seek", "train", "cooldown"]
    warm, seek, train, cool = phases
    assert warm["t_start"] == 0.0 and warm["t_end"] == pytest.approx(5.0)
    assert seek["t_end"] - seek["t_start"] < 60.0
    # tracked through the training (the seeker's track phase): the optimum at its end is the
    # session's, and both the search's own and where the tracking ended are within the
    # person's 99 % band (a flat Hill top, where ±13 % in w costs 0.7 % of the power: the
    # track phase wanders that far over noise seeds 1, 2, 3 and 5, either way; brent's own
    # ended 11 % high on seed 2). The Hill curve written out, τ = τ0 (wmax − w)/(wmax + w/a),
    # its power maximised on a grid.
    assert train["optimum_w"] == pytest.approx(s["optimum_w"])
    w = np.linspace(0.01, HILL["wmax"] - 0.01, 200_000)

    def power(v: np.ndarray) -> np.ndarray:
        a, tau0, wmax = HILL["curvature"], HILL["tau0"], HILL["wmax"]
        return v * tau0 * (wmax - v) / (wmax + v / a)

    p_star = float(power(w).max())
    assert float(power(np.array([seek["optimum_w"]]))[0]) >= 0.99 * p_star
    assert float(power(np.array([s["optimum_w"]]))[0]) >= 0.99 * p_star
    # converged inside the bracket: no phase's optimum is an edge
    assert [p["at_bound"] for p in phases] == [None] * 4 and s["at_bound"] is None
    assert train["t_end"] - train["t_start"] == pytest.approx(2.0 + 2 * 20.0)
    assert [i["interval"] for i in train["detail"]["intervals"]] == [1, 2]
    assert cool["t_end"] - cool["t_start"] >= 5.0 + 1.0
    assert all(a["t_end"] == b["t_start"] for a, b in itertools.pairwise(phases))
    # the end, as stored: still, and no torque once the person has relaxed
    c = stored(server, ran["sid"], ("t", "w", "u"))
    last = c["t"] >= c["t"][-1] - 0.5
    assert np.abs(c["w"][last]).max() < 0.05 and np.abs(c["u"][last]).max() < 0.05
    assert c["t"][-1] == pytest.approx(cool["t_end"], abs=0.002)


def test_the_live_stream_says_which_phase_runs_and_what_comes_next(ran: dict[str, Any]) -> None:
    assert ran["joined"]["kind"] == "warmup" and ran["joined"]["next_kind"] == "seek"
    firsts = [st for st in ran["stages"] if st["segment"] == 0]
    assert [st["kind"] for st in firsts] == ["warmup", "seek", "train", "cooldown"]
    assert [st["next_kind"] for st in firsts] == ["seek", "train", "cooldown", None]
    roles = [st["role"] for st in ran["stages"] if st["kind"] == "train"]
    assert roles == ["countdown", "work", "rest", "countdown", "work", "rest"]
    assert ran["stage_column"] == {0.0, 1.0, 2.0, 3.0}  # every telemetry frame carries it
    live = ran["live"]
    assert live["stage"]["role"] == "work" and live["stage"]["kind"] == "train"
    assert 0.0 <= live["time_left"] <= 10.0 and live["phase_time_left"] >= live["time_left"]


def test_the_fit_file_decodes_to_the_stored_telemetry_with_a_lap_per_phase(
    server: ServerProcess, ran: dict[str, Any]
) -> None:
    sid = ran["sid"]
    started = ran["body"]["session"]["started_at"]
    with server.client("viewer") as c:
        for interval in (1, 3):
            r = c.get(f"/api/v1/sessions/{sid}/activity.fit", params={"interval": interval})
            assert r.status_code == 200 and r.headers["content-type"] == "application/vnd.ant.fit"
            msgs = decode_fit(r.content)
            cols = stored(server, sid, ("t", "w", "tau", "wd"))
            bins = record_bins(cols["t"], datetime.fromisoformat(started), interval)
            records = msgs["record"]
            assert len(records) == len(bins)
            for rec, (stamp, m) in zip(records, bins, strict=True):
                assert rec["timestamp"].timestamp() == stamp
                rpm = max(float(np.mean(cols["w"][m])) * RPM, 0.0)
                assert rec["cadence"] + rec["fractional_cadence"] == round(rpm * 128) / 128
                tau = cols["tau"][m]
                known = np.isfinite(tau)  # the torque ramp's records have no τ̂ (NaN)
                if not known.any():
                    assert "mean_power" not in rec and "torque" not in rec
                    continue
                power = float(np.mean(tau[known] * cols["w"][m][known]))
                assert rec["mean_power"] == np.float32(power)
                assert rec["power"] == max(round(power), 0)
                assert rec["torque"] == np.float32(np.mean(tau[known]))
    laps, phases = msgs["lap"], ran["phases"]
    assert [lap["phase"] for lap in laps] == [p["name"] for p in phases]
    for lap, p in zip(laps, phases, strict=True):
        assert lap["total_elapsed_time"] == pytest.approx(p["t_end"] - p["t_start"], abs=1e-3)
        assert lap["avg_power"] == round(p["mean_power"])
    assert [lap["intensity"] for lap in laps] == ["warmup", "active", "active", "cooldown"]


def test_the_report_opens_with_the_users_name_and_the_optimum(
    server: ServerProcess, ran: dict[str, Any]
) -> None:
    sid, s = ran["sid"], ran["body"]["session"]
    with server.client("viewer") as c:
        r = c.get(f"/api/v1/sessions/{sid}/report.pdf")
        assert r.status_code == 200 and r.headers["content-type"] == "application/pdf"
        pdf = pypdf.PdfReader(io.BytesIO(r.content))
        assert len(pdf.pages) == 1
        text = pdf.pages[0].extract_text()
        assert "Zoë Ødegård" in text
        assert f"{s['optimum_w'] * RPM:.3g} rpm" in text  # the viewer's default unit
        assert f"({s['peak_power'] / 64.0:.2f} W/kg)" in text
        assert "warm, seek, 2 × 10/10, cool" in text
        r = c.get(f"/api/v1/sessions/{sid}/report.pdf", params={"velocity_unit": "rad/s"})
        text = pypdf.PdfReader(io.BytesIO(r.content)).pages[0].extract_text()
        assert f"{s['optimum_w']:.3g} rad/s" in text


def test_exports_refuse_what_they_cannot_make(server: ServerProcess, ran: dict[str, Any]) -> None:
    sid = ran["sid"]
    with server.client(None) as anon:
        assert anon.get(f"/api/v1/sessions/{sid}/report.pdf").status_code == 401
    with server.client("viewer") as c:
        assert c.get("/api/v1/sessions/999999/activity.fit").status_code == 404
        assert c.get("/api/v1/sessions/999999/report.pdf").status_code == 404
        bad = c.get(f"/api/v1/sessions/{sid}/activity.fit", params={"interval": 0})
        assert bad.status_code == 422 and bad.json()["detail"][0]["loc"] == ["query", "interval"]
        bad = c.get(f"/api/v1/sessions/{sid}/report.pdf", params={"tz": "Mars/Olympus"})
        assert bad.status_code == 422 and "time zone" in bad.text
    with server.client("trainer") as c:
        start = c.post("/api/v1/sessions", json={"user_id": ran["user"]["id"], "duration": 30})
        running = start.json()["id"]
        try:
            for path in ("report.pdf", "activity.fit"):
                r = c.get(f"/api/v1/sessions/{running}/{path}")
                assert r.status_code == 409 and "running" in r.json()["detail"]
        finally:
            c.post(f"/api/v1/sessions/{running}/stop")
        server.wait_status(running, ENDED, 30)


def test_progress_overlay_and_preferences(server: ServerProcess, ran: dict[str, Any]) -> None:
    uid, sid, s = ran["user"]["id"], ran["sid"], ran["body"]["session"]
    with server.client("viewer") as c:
        pr = c.get(f"/api/v1/users/{uid}/progress").json()
        point = next(p for p in pr["sessions"] if p["session_id"] == sid)
        assert point["protocol"] == PROTOCOL["name"] and point["optimum_w"] == s["optimum_w"]
        assert point["peak_power_per_kg"] == pytest.approx(s["peak_power"] / 64.0)
        assert point["mean_power_per_kg"] == pytest.approx(s["mean_power"] / 64.0)
        assert "rad/s" in pr["units"]
        ov = c.get(f"/api/v1/sessions/{sid}/overlay",
                   params={"with": sid, "align": "train", "points": 100}).json()  # fmt: skip
        train = next(p for p in ran["phases"] if p["kind"] == "train")
        a, b = ov["sessions"]
        assert a["offset"] == b["offset"] == train["t_start"] and a["channels"] == b["channels"]
        t = np.array(ov["t"])
        assert len(t) == 100 and t[0] < 0.0 < t[-1]  # the warm-up and seek before t = 0
        w = np.array([np.nan if x is None else x for x in a["channels"]["w"]])
        cols = stored(server, sid, ("t", "w"))
        half = (t[1] - t[0]) / 2
        k = 60  # one bucket, by hand
        m = (cols["t"] - train["t_start"] >= t[k] - half) & (
            cols["t"] - train["t_start"] < t[k] + half)  # fmt: skip
        assert w[k] == pytest.approx(float(cols["w"][m].mean()), rel=1e-9)
        bad = c.get(f"/api/v1/sessions/{sid}/overlay", params={"with": sid, "align": "profile"})
        assert bad.status_code == 422 and "no profile phase" in bad.text
        assert c.get("/api/v1/accounts/me/preferences").json() == {"velocity_unit": "rpm"}
        put = c.put("/api/v1/accounts/me/preferences", json={"velocity_unit": "rad/s"})
        assert put.status_code == 200 and put.json() == {"velocity_unit": "rad/s"}
        bad = c.put("/api/v1/accounts/me/preferences", json={"velocity_unit": "deg/s"})
        assert bad.status_code == 422 and bad.json()["detail"][0]["loc"][-1] == "velocity_unit"
        assert c.get("/api/v1/accounts/me/preferences").json() == {"velocity_unit": "rad/s"}
        r = c.get(f"/api/v1/sessions/{sid}/report.pdf")  # the viewer's unit now
        text = pypdf.PdfReader(io.BytesIO(r.content)).pages[0].extract_text()
        assert f"{s['optimum_w']:.3g} rad/s" in text
    with server.client("trainer") as c:  # a preference is the account's own
        assert c.get("/api/v1/accounts/me/preferences").json() == {"velocity_unit": "rpm"}


def test_a_bad_protocol_is_422_naming_the_field_and_starts_nothing(
    server: ServerProcess, ran: dict[str, Any]
) -> None:
    uid = ran["user"]["id"]
    with server.client("trainer") as c:
        before = c.get("/api/v1/sessions", params={"user_id": uid}).json()["total"]
        cases = [
            ({"phases": [{"kind": "train", "work": 0}]},
             ["protocol", "phases", 0, "train", "work"]),
            ({"phases": [{"kind": "train", "velocity": 14.0}]},
             ["protocol", "phases", "0", "velocity"]),
        ]  # fmt: skip
        for protocol, loc in cases:
            r = c.post("/api/v1/sessions", json={"user_id": uid, "protocol": protocol})
            assert r.status_code == 422, r.text
            got = r.json()["detail"][0]
            assert [str(x) for x in got["loc"][-len(loc) :]] == [str(x) for x in loc], got
        r = c.post("/api/v1/sessions", json={"user_id": uid, "template_id": 99999})
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "template_id"]
        r = c.post("/api/v1/sessions", json={"user_id": uid, "template_id": ran["template"]["id"],
                                             "protocol": PROTOCOL})  # fmt: skip
        assert r.status_code == 422 and "not both" in r.text
        assert c.get("/api/v1/sessions", params={"user_id": uid}).json()["total"] == before


@pytest.fixture(scope="module")
def pg_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    pg = postgres()
    url = pg.create_database()
    try:
        with start_server(tmp_path_factory.mktemp("pg"),
                          env={"ERGOSEEK_DATABASE_URL": url}) as srv:  # fmt: skip
            yield srv
    finally:
        pg.drop_database(url)


def test_a_protocol_session_on_postgresql_whose_seek_ends_at_the_bracket(
    pg_server: ServerProcess,
) -> None:
    # w* = 7.7 rad/s (the Hill person's closed form) above the trainer's [1, 3] rad/s: the
    # seek phase ends at the upper edge, and its stored phase says so (the others do not)
    protocol = {"phases": [{"kind": "warmup", "duration": 3.0},
                           {"kind": "seek", "duration": 40.0, "hold": 0.5},
                           {"kind": "cooldown", "duration": 3.0}]}  # fmt: skip
    person = {"kind": "hill", "tau0": 3.0, "wmax": 7.7 / 0.30902}
    assert pg_server.database_url.startswith("postgresql")
    with pg_server.client("trainer") as c:
        user = c.post("/api/v1/users", json={"name": "Pia", "sim_profile": person}).json()
        r = c.post("/api/v1/sessions", json={"user_id": user["id"], "protocol": protocol,
                                             "seeker": {"bracket": [1.0, 2.0, 3.0]},
                                             "seed": 1})  # fmt: skip
        assert r.status_code == 201, r.text
        sid = r.json()["id"]
    body = pg_server.wait_status(sid, ENDED, 90)
    assert body["session"]["status"] == "completed"
    phases = wait_phases(pg_server, sid)
    assert [p["kind"] for p in phases] == ["warmup", "seek", "cooldown"]
    assert all(p["mean_power"] is not None for p in phases)
    assert [p["at_bound"] for p in phases] == [None, "upper", None]
    assert phases[1]["optimum_w"] == pytest.approx(3.0, rel=0.03)
    assert phases[1]["t_end"] - phases[1]["t_start"] < 40.0  # it ended there, by itself
    with pg_server.client("viewer") as c:
        fit = decode_fit(c.get(f"/api/v1/sessions/{sid}/activity.fit").content)
        assert [lap["phase"] for lap in fit["lap"]] == [p["name"] for p in phases]
    c_ = stored(pg_server, sid, ("t", "w", "u"))
    assert abs(c_["w"][-1]) < 0.05 and abs(c_["u"][-1]) < 0.05
