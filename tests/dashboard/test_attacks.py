"""The dashboard as an attacker tries it (issue 12.3), with raw WebSocket clients speaking
viser's wire format (:mod:`testing.viser_wire`) against ``ergoseek demo`` in its own process:

- nothing of the dashboard listens on TCP but the web server itself (a local process reaching
  viser directly gets no frame);
- through the proxy, a logged-in trainer cannot rewire or remove the E-STOP (``update_cb``,
  ``removed``…): the E-STOP still stops the machine;
- one trainer's session form is theirs: another trainer's values never reach it, even sent
  to its element ids; a viewer's History selection is theirs;
- a demoted or disabled account loses the trainers' dashboard at once;
- users added over REST appear in the open dashboards without a restart.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from sessions.config import SeekerConfig
from testing.browser import TRAINER, DemoServer
from testing.viser_wire import RawClient, gui_update, open_proxy, open_tcp, tcp_listeners

COACH, COACH_PASSWORD = "coach2", "coach-two-Vq83-wkzP"
CHIEF, CHIEF_PASSWORD = "chief", "chief-admin-Rt5b-Lm29-xQ"
VIEWER_A, VIEWER_B, VIEWER_PASSWORD = "watcher", "watcher2", "viewer-Jt61-pqZa"
DEMOTED, DEMOTED_PASSWORD = "soon-viewer", "soon-viewer-Hy47-nbE"
DISABLED, DISABLED_PASSWORD = "soon-gone", "soon-gone-Wc92-kLd"
ACCOUNTS = [
    (COACH, COACH_PASSWORD, "trainer"),
    (CHIEF, CHIEF_PASSWORD, "admin"),
    (VIEWER_A, VIEWER_PASSWORD, "viewer"),
    (VIEWER_B, VIEWER_PASSWORD, "viewer"),
    (DEMOTED, DEMOTED_PASSWORD, "trainer"),
    (DISABLED, DISABLED_PASSWORD, "trainer"),
]
ADA = "Ada (#1)"  # the first demo user


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DemoServer]:
    demo = DemoServer(tmp_path_factory.mktemp("attacks"), accounts=ACCOUNTS)
    with demo:
        yield demo
    print(demo.log()[-3000:])


def login_headers(server: DemoServer, login: str) -> dict[str, str]:
    """A browser's headers after logging in as ``login``: the cookie and our Origin."""
    with server.client(login) as c:
        cookie = c.cookies["ergoseek_session"]
    return {"Cookie": f"ergoseek_session={cookie}", "Origin": server.url}


@contextlib.contextmanager
def dashboard(server: DemoServer, login: str) -> Iterator[RawClient]:
    """A raw client through ``/dashboard``, logged in as ``login``, past its first camera
    message (so viser builds what that login gets)."""
    with open_proxy(server.ws_url + "/dashboard", login_headers(server, login)) as client:
        client.receive(0.5)
        client.hello()
        yield client


def machine_state(server: DemoServer) -> str:
    with server.client(TRAINER) as api:
        return str(api.get("/api/v1/machine").json()["state"])


def wait_state(server: DemoServer, wanted: str, timeout: float = 10.0) -> str:
    deadline = time.monotonic() + timeout
    state = machine_state(server)
    while state != wanted and time.monotonic() < deadline:
        time.sleep(0.1)
        state = machine_state(server)
    return state


def reset_machine(server: DemoServer) -> None:
    with server.client(TRAINER) as api:
        api.post("/api/v1/machine/reset").raise_for_status()
    assert wait_state(server, "idle") == "idle"


def test_nothing_but_the_web_server_listens_on_tcp(server: DemoServer) -> None:
    listening = tcp_listeners(server.pid)
    others = {port for _, port in listening if port != server.port}
    reached = {}
    for port in sorted(others):  # a local process talking to it straight
        try:
            with open_tcp(f"ws://127.0.0.1:{port}") as raw:
                raw.hello()
                reached[port] = sorted({m["type"] for m in raw.receive(2.0)})
        except Exception as exc:  # refused: fine, but it should not listen at all
            reached[port] = [f"refused: {exc!r}"]
    assert {port for _, port in listening} == {server.port}, reached


def test_the_e_stop_cannot_be_rewired_from_a_client_message(server: DemoServer) -> None:
    assert machine_state(server) == "idle"
    with dashboard(server, TRAINER) as attacker:
        estop = attacker.wait_for("E-STOP", "GuiButtonMessage")
        for attack in (
            {"update_cb": []},
            {"removed": True},
            {"sync_cb": None},
            {"is_button": False},
            {"props": {}},
            {"value": True, "update_cb": []},
        ):
            attacker.send(gui_update(estop, **attack))
        attacker.receive(1.0)
        assert machine_state(server) == "idle"  # (none of that was a click)
        # The attacker's own E-STOP still stops the machine...
        attacker.send(gui_update(estop, value=True))
        assert wait_state(server, "estopped") == "estopped"
    reset_machine(server)
    # ...and so does the E-STOP of the next dashboard opened (nothing was left broken).
    with dashboard(server, COACH) as trainer:
        trainer.send(gui_update(trainer.wait_for("E-STOP", "GuiButtonMessage"), value=True))
        assert wait_state(server, "estopped") == "estopped"
    reset_machine(server)


def latest_session(server: DemoServer) -> dict[str, Any]:
    with server.client(TRAINER) as api:
        page = api.get("/api/v1/sessions", params={"limit": 1}).json()
        return dict(page["items"][0]) if page["items"] else {}


def test_one_trainers_form_is_not_another_trainers(server: DemoServer) -> None:
    before = latest_session(server).get("id")
    with dashboard(server, TRAINER) as mine, dashboard(server, COACH) as other:
        user, duration = mine.wait_for("User"), mine.wait_for("Duration (s)")
        mine.send(gui_update(user, value=ADA))
        mine.send(gui_update(duration, value=7.0))
        mine.receive(0.5)
        # The other trainer writes into every setup field it has, and into every element id
        # it ever saw of the first trainer's (a per-browser GUI must ignore them all).
        theirs = {
            label: other.wait_for(label)
            for label in ("User", "Duration (s)", "ks", "Seeker", "Controller")
        }
        attack = {"Duration (s)": 3600.0, "ks": 500.0, "Seeker": "fixed"}
        for label, value in attack.items():
            other.send(gui_update(theirs[label], value=value))
            uuid = mine.find(label)
            assert uuid is not None
            other.send(gui_update(uuid, value=value))
        other.receive(1.0)
        mine.receive(0.5)
        assert mine.updates_of(duration)[-1:] != [{"value": 3600.0}]
        mine.send(gui_update(mine.wait_for("Start", "GuiButtonMessage"), value=True))
        deadline = time.monotonic() + 20
        session = latest_session(server)
        while session.get("id") == before and time.monotonic() < deadline:
            time.sleep(0.2)
            session = latest_session(server)
    assert session.get("id") != before, "the first trainer's Start started nothing"
    with server.client(TRAINER) as api:
        detail = api.get(f"/api/v1/sessions/{session['id']}").json()["session"]
        if detail["status"] == "running":
            api.post(f"/api/v1/sessions/{session['id']}/stop")
    cfg = detail["config"]
    assert cfg["duration"] == 7.0
    assert cfg["controller"]["ks"] != 500.0
    assert cfg["seeker"]["kind"] == SeekerConfig().kind  # the form's default, not "fixed"
    assert wait_state(server, "idle", 30.0) == "idle"


def test_a_viewers_history_pick_is_their_own(server: DemoServer) -> None:
    with dashboard(server, VIEWER_A) as a, dashboard(server, VIEWER_B) as b:
        assert a.find("E-STOP") is None and b.find("E-STOP") is None  # viewers: no controls
        mine, theirs = a.wait_for("History of"), b.wait_for("History of")
        options = next(m["props"]["options"] for m in b.elements() if m["uuid"] == theirs)
        other_user = next(o for o in options if o != ADA and "#" in o)
        a.send(gui_update(mine, value=other_user))
        a.send(gui_update(theirs, value=other_user))  # even with the other viewer's id
        a.receive(1.5)
        b.receive(1.0)
        assert {"value": other_user} not in b.updates_of(theirs)
        assert {"value": other_user} not in b.updates_of(mine)


def closed_within(client: RawClient, seconds: float) -> float | None:
    """Seconds until the server closed the connection, or None if it stayed open."""
    started = time.monotonic()
    while time.monotonic() - started < seconds:
        client.receive(0.1)
        if client.closed is not None:
            return time.monotonic() - started
    return None


def test_a_demoted_or_disabled_trainer_loses_the_controls_at_once(server: DemoServer) -> None:
    with server.client(CHIEF) as admin:
        accounts = {a["login"]: a["id"] for a in admin.get("/api/v1/accounts").json()}
    headers = login_headers(server, DEMOTED)
    with open_proxy(server.ws_url + "/dashboard", headers) as trainer:
        trainer.hello()
        trainer.wait_for("E-STOP", "GuiButtonMessage")
        with server.client(CHIEF) as admin:
            r = admin.patch(f"/api/v1/accounts/{accounts[DEMOTED]}", json={"role": "viewer"})
            r.raise_for_status()
        after = closed_within(trainer, 20.0)
    assert after is not None and after < 2.0, f"still connected {after} s after the demotion"
    # The page reconnects with the same login: now the viewers' dashboard, no controls.
    with open_proxy(server.ws_url + "/dashboard", headers) as viewer:
        viewer.hello()
        viewer.wait_for("History of")
        viewer.receive(1.0)
        assert viewer.find("E-STOP") is None and viewer.find("Start") is None

    headers = login_headers(server, DISABLED)
    with open_proxy(server.ws_url + "/dashboard", headers) as trainer:
        trainer.hello()
        trainer.wait_for("E-STOP", "GuiButtonMessage")
        with server.client(CHIEF) as admin:
            r = admin.patch(f"/api/v1/accounts/{accounts[DISABLED]}", json={"disabled": True})
            r.raise_for_status()
        after = closed_within(trainer, 20.0)
    assert after is not None and after < 2.0, f"still connected {after} s after disabling"


def options_seen(client: RawClient, uuid: str) -> list[str]:
    """The latest options the client was sent for a dropdown."""
    options: list[str] = next(m["props"]["options"] for m in client.elements() if m["uuid"] == uuid)
    for update in client.updates_of(uuid):
        options = update.get("options", options)
    return list(options)


def test_users_added_over_rest_appear_in_open_dashboards(server: DemoServer) -> None:
    with dashboard(server, TRAINER) as trainer, dashboard(server, VIEWER_A) as viewer:
        picker, history = trainer.wait_for("User"), viewer.wait_for("History of")
        with server.client(COACH) as api:
            r = api.post("/api/v1/users", json={"name": "Added over REST"})
            r.raise_for_status()
            label = f"Added over REST (#{r.json()['id']})"
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            trainer.receive(0.2)
            viewer.receive(0.2)
            if label in options_seen(trainer, picker) and label in options_seen(viewer, history):
                break
        assert label in options_seen(trainer, picker)
        assert label in options_seen(viewer, history)
        with server.client(COACH) as api:  # renamed over REST: renamed on the page
            api.patch(
                f"/api/v1/users/{r.json()['id']}", json={"name": "Renamed"}
            ).raise_for_status()
        renamed = f"Renamed (#{r.json()['id']})"
        deadline = time.monotonic() + 10.0
        while renamed not in options_seen(trainer, picker) and time.monotonic() < deadline:
            trainer.receive(0.2)
        assert renamed in options_seen(trainer, picker)
        assert label not in options_seen(trainer, picker)


def test_the_raw_client_tooling_reads_the_dashboard(server: DemoServer) -> None:
    """(The tests above are only as good as the raw client: it sees what a browser sees.)"""
    with dashboard(server, TRAINER) as trainer:
        for label in ("E-STOP", "Start", "Stop", "Reset", "User", "Duration (s)"):
            assert trainer.wait_for(label)
    assert Path(f"/proc/{server.pid}").exists()
