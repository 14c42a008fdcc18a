"""The dashboard as an attacker tries it (issue 12.3), with raw WebSocket clients speaking
viser's wire format (:mod:`testing.viser_wire`) against ``ergoseek demo`` in its own process:

- nothing of the dashboard listens on TCP but the web server itself (a local process reaching
  viser directly gets no frame);
- through the proxy, a logged-in trainer cannot rewire or remove the E-STOP (``update_cb``,
  ``removed``…): the E-STOP still stops the machine;
- one trainer's session form is theirs: another trainer's values never reach it, even sent
  to its element ids; a viewer's History selection is theirs;
- a demoted or disabled account loses the trainers' dashboard at once;
- users added over REST appear in the open dashboards without a restart;
- the caps of docs/dashboard.md: past 8 sockets of one account or 32 in all the handshake is
  refused (403) until one closes; a socket that stops reading is dropped after 10 s (the
  server's close frame, 1008) while the others keep receiving; Start is disabled while a
  session runs, and a press then never reaches its callback.
"""

from __future__ import annotations

import base64
import contextlib
import os
import socket
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from websockets.client import ClientProtocol
from websockets.exceptions import InvalidStatus
from websockets.frames import Close, Frame, Opcode
from websockets.protocol import State
from websockets.uri import parse_uri

from sessions.config import SeekerConfig
from testing.browser import TRAINER, DemoServer
from testing.viser_wire import (
    CAMERA,
    SUBPROTOCOL,
    RawClient,
    decode,
    encode,
    gui_update,
    open_proxy,
    open_tcp,
    tcp_listeners,
)

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


# -- the dashboard's caps: connections, slow readers (docs/dashboard.md, "Proxy and login") ---
MAX_OPEN, MAX_PER_ACCOUNT = 32, 8  # "past 32 open dashboards (8 of one account)": refused


def handshake(server: DemoServer, headers: dict[str, str]) -> RawClient | int:
    """An open dashboard socket, or the HTTP status its handshake was refused with."""
    try:
        return open_proxy(server.ws_url + "/dashboard", headers)
    except InvalidStatus as exc:
        return exc.response.status_code


def open_when_free(server: DemoServer, headers: dict[str, str], timeout: float = 10.0) -> RawClient:
    """A socket as soon as a slot has been freed (the server counts a closed one out once its
    relay has ended)."""
    deadline = time.monotonic() + timeout
    while True:
        got = handshake(server, headers)
        if isinstance(got, RawClient):
            return got
        assert got == 403 and time.monotonic() < deadline, f"no slot freed ({got})"
        time.sleep(0.1)


def test_the_connection_caps_refuse_the_next_socket_until_one_closes(server: DemoServer) -> None:
    heads = {login: login_headers(server, login) for login in (TRAINER, COACH, CHIEF, VIEWER_A)}
    extra = login_headers(server, VIEWER_B)
    opened: list[RawClient] = []
    try:
        for _ in range(MAX_PER_ACCOUNT):  # one account's eight: let in
            got = handshake(server, heads[TRAINER])
            assert isinstance(got, RawClient), got
            opened.append(got)
        assert handshake(server, heads[TRAINER]) == 403  # its ninth: refused
        other = handshake(server, heads[COACH])  # (another account is not)
        assert isinstance(other, RawClient), other
        other.close()
        opened.pop(0).close()  # one of the eight closes: the account may open one again
        opened.append(open_when_free(server, heads[TRAINER]))
        for login in (COACH, CHIEF, VIEWER_A):  # 32 open in all
            for _ in range(MAX_PER_ACCOUNT):
                got = handshake(server, heads[login])
                assert isinstance(got, RawClient), (login, got)
                opened.append(got)
        assert handshake(server, extra) == 403  # the 33rd, of an account with none open
        opened.pop().close()
        opened.append(open_when_free(server, extra))
        assert handshake(server, heads[COACH]) == 403  # full again
        for client in opened:  # every one of them is a live dashboard socket
            client.receive(0.05)
            assert client.closed is None
    finally:
        for client in opened:
            client.close()


def until(what: str, done: Callable[[], object], timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not done():
        assert time.monotonic() < deadline, what
        time.sleep(0.1)


SEND_TIMEOUT_S = 10.0  # "a browser that does not take a frame for 10 s is dropped"


def stuck_reader(server: DemoServer, headers: dict[str, str]) -> socket.socket:
    """A dashboard socket that says hello and then never reads again: a plain TCP socket with
    the smallest receive buffer, the WebSocket handshake done by hand."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # (before connect: the window)
    sock.settimeout(10.0)
    sock.connect(("127.0.0.1", server.port))
    key = base64.b64encode(os.urandom(16)).decode()
    lines = [
        "GET /dashboard HTTP/1.1",
        f"Host: 127.0.0.1:{server.port}",
        "Upgrade: websocket",
        "Connection: Upgrade",
        f"Sec-WebSocket-Key: {key}",
        "Sec-WebSocket-Version: 13",
        f"Sec-WebSocket-Protocol: {SUBPROTOCOL}",
        *(f"{k}: {v}" for k, v in headers.items()),
    ]
    sock.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
    head = b""
    while b"\r\n\r\n" not in head:
        chunk = sock.recv(1)  # byte by byte: nothing of the frames after it is taken
        assert chunk, "closed during the handshake"
        head += chunk
    assert head.startswith(b"HTTP/1.1 101"), head
    sock.sendall(Frame(Opcode.BINARY, encode(CAMERA)).serialize(mask=True))  # viser: a client
    return sock


def closed_by_server(sock: socket.socket, url: str, timeout: float) -> tuple[Close | None, int]:
    """Read the socket (the server's frames, parsed by ``websockets``' own protocol) until the
    server's close frame, its EOF or the timeout: (the close frame if any, bytes read)."""
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)  # (a wider window: quicker)
    sock.settimeout(1.0)
    wire = ClientProtocol(parse_uri(url), state=State.OPEN, max_size=None)
    total, deadline = 0, time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            chunk = sock.recv(1 << 16)
        except TimeoutError:
            continue
        except ConnectionResetError:
            break
        if not chunk:
            break
        total += len(chunk)
        wire.receive_data(chunk)
        for frame in wire.events_received():
            if frame.opcode is Opcode.CLOSE:
                return Close.parse(frame.data), total
    return None, total


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


def test_a_browser_that_stops_reading_is_dropped_and_the_others_keep_receiving(
    server: DemoServer,
) -> None:
    dropped = "dashboard socket of demo closed: the browser stopped reading"
    assert dropped not in server.log()
    with server.client(TRAINER) as api, dashboard(server, COACH) as good:
        r = api.post("/api/v1/sessions", json={"user_id": 1, "duration": 120})  # a stream
        assert r.status_code == 201, r.text
        try:
            slow = stuck_reader(server, login_headers(server, TRAINER))
            rss0, began = rss_mb(server.pid), time.monotonic()
            arrivals: list[float] = []
            while dropped not in server.log():  # the good one reads on, the slow one never
                assert time.monotonic() - began < SEND_TIMEOUT_S + 30.0, "never dropped"
                try:
                    frame = good.ws.recv(timeout=0.2)
                except TimeoutError:
                    continue
                arrivals.append(time.monotonic())
                assert isinstance(frame, bytes) and decode(frame)
            stuck_for, rss1 = time.monotonic() - began, rss_mb(server.pid)
            assert stuck_for >= SEND_TIMEOUT_S  # (it had a full 10 s to take a frame)
            # dropped: what reaches the slow socket now is its backlog, then a close frame
            # (a stuck socket would stream on)
            close, backlog = closed_by_server(slow, server.ws_url + "/dashboard", 15.0)
            slow.close()
            assert close is not None, f"no close frame after {backlog} bytes"
            assert (close.code, close.reason) == (1008, "too slow"), close
            # the others never waited for it: frames all along (~25 a second), no stall
            gaps = np.diff([began, *arrivals])
            assert len(arrivals) >= 10 * stuck_for and gaps.max() < 2.0, (len(arrivals), gaps.max())
            assert rss1 - rss0 < 64, (rss0, rss1)  # bounded by the drop: no unbounded backlog
            assert good.receive(1.0) and good.closed is None  # and still receiving after it
        finally:  # (an e-stop and a reset: quicker than winding the session down to rest)
            assert api.post("/api/v1/machine/estop").status_code == 202
            until("e-stopped", lambda: api.get("/api/v1/machine").json()["state"] == "estopped")
            assert api.post("/api/v1/machine/reset").status_code == 202
            until("reset", lambda: api.get("/api/v1/machine").json()["state"] == "idle")


def disabled(client: RawClient, uuid: str) -> bool:
    """Whether the client was last told that the element is disabled."""
    now = bool(next(m["props"]["disabled"] for m in client.elements() if m["uuid"] == uuid))
    for update in client.updates_of(uuid):
        now = bool(update.get("disabled", now))
    return now


def wait_disabled(client: RawClient, uuid: str, wanted: bool, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while disabled(client, uuid) != wanted:
        assert time.monotonic() < deadline, f"Start never became disabled={wanted}"
        client.receive(0.2)


def said(messages: list[dict[str, Any]]) -> str:
    """Everything the dashboard wrote in these messages: its texts' updates (viser sends a
    markdown element's text as ``_markdown``, an HTML element's as ``content``)."""
    texts = []
    for m in messages:
        if m.get("type") == "GuiUpdateMessage":
            texts += [str(m["updates"][k]) for k in ("_markdown", "content") if k in m["updates"]]
    return " ".join(texts)


def session_ids(api: httpx.Client) -> set[int]:
    return {s["id"] for s in api.get("/api/v1/sessions", params={"limit": 100}).json()["items"]}


def test_start_is_disabled_while_a_session_runs_and_a_press_starts_nothing(
    server: DemoServer,
) -> None:
    with server.client(TRAINER) as api, dashboard(server, COACH) as trainer:

        def state() -> dict[str, Any]:
            return dict(api.get("/api/v1/machine").json())

        until("the machine is idle", lambda: state()["state"] == "idle")
        start = trainer.wait_for("Start", "GuiButtonMessage")
        trainer.send(gui_update(trainer.wait_for("User"), value=ADA))
        wait_disabled(trainer, start, False)
        r = api.post("/api/v1/sessions", json={"user_id": 1, "duration": 120})  # over REST
        assert r.status_code == 201, r.text
        running = r.json()["id"]
        try:
            wait_disabled(trainer, start, True)
            before = session_ids(api)
            for _ in range(3):  # a press: what a browser would send for a click
                trainer.send(gui_update(start, value=True))
            after_press = trainer.receive(1.5)
            # dropped in the view (a disabled element takes no value): the Start callback
            # never ran, so it never even said "starting…" or "Not started: …"
            assert "starting…" not in said(after_press) and "Not started" not in said(after_press)
            assert session_ids(api) == before and state()["session_id"] == running
            assert api.post(f"/api/v1/sessions/{running}/stop").status_code == 202
            until("the session ended", lambda: state()["state"] == "idle")
            wait_disabled(trainer, start, False)  # enabled again once the session has ended
            # ...and a press now starts a session (the presses above were really ignored)
            trainer.send(gui_update(start, value=True))
            until("the re-enabled Start started nothing", lambda: session_ids(api) - before)
            (pressed,) = session_ids(api) - before
            wait_disabled(trainer, start, True)
            deadline = time.monotonic() + 10.0  # (and said so: `said` reads what it says)
            while f"started by {COACH}" not in said(trainer.messages):
                assert time.monotonic() < deadline, said(trainer.messages)[-500:]
                trainer.receive(0.2)
        finally:  # (an e-stop and a reset: quicker than winding a session down to rest)
            assert api.post("/api/v1/machine/estop").status_code == 202
            until("e-stopped", lambda: state()["state"] == "estopped")
            assert api.post("/api/v1/machine/reset").status_code == 202
            until("reset", lambda: state()["state"] == "idle")
    with server.client(COACH) as coach:  # the press was this dashboard's trainer's
        me = coach.get("/api/v1/auth/me").json()["account"]["id"]
        assert coach.get(f"/api/v1/sessions/{pressed}").json()["session"]["account_id"] == me
