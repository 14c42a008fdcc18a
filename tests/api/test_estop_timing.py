"""An e-stop over HTTP, timed at the motor: ``ergoseek serve --machine odrive`` drives an
ODrive this test emulates on a pty of its own, so the device's log of every torque setpoint
(arrival time on CLOCK_MONOTONIC, which the test shares) says when zero torque reached it.
The clock starts as the request is sent on a connection opened beforehand (so before the
gate accepted it: the figure is an upper bound of accepted → zero); :data:`ZERO_WITHIN` is
the fixed bound a 60 ms delay anywhere on the path (gate, e-stop line, the worker's e-stop
branch) breaks.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from sessions.machine.odrive.emulator import EmulatorConfig, EmulatorProcess
from testing.live import EMULATED_KT, wait_for
from testing.server import ServerProcess, start_server

pytestmark = pytest.mark.realtime  # timed where it happens: alone, after the parallel rooms

ZERO_WITHIN = 0.030  # s from the request sent to zero torque at the device


@pytest.fixture(scope="module")
def rig(
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[tuple[ServerProcess, EmulatorProcess]]:
    env = {
        "ERGOSEEK_TORQUE_CONSTANT": str(EMULATED_KT),
        "ERGOSEEK_REPLY_TIMEOUT": "0.15",  # a loaded VM stalls a pty for tens of ms
        "ERGOSEEK_WATCHDOG_TIMEOUT": "0.4",
    }
    data: Path = tmp_path_factory.mktemp("estop-timing")
    with (
        EmulatorProcess(EmulatorConfig()) as emu,
        start_server(data, "--machine", "odrive", "--device", emu.path, env=env) as srv,
    ):
        yield srv, emu


def _estop(srv: ServerProcess, token: str) -> tuple[float, int]:
    """``POST /api/v1/machine/estop`` on a connection opened beforehand (so the clock times
    the request, not the client library's setup): the monotonic time it was sent, the status."""
    request = (
        f"POST /api/v1/machine/estop HTTP/1.1\r\nHost: 127.0.0.1:{srv.port}\r\n"
        f"Authorization: Bearer {token}\r\nContent-Length: 0\r\nConnection: close\r\n\r\n"
    ).encode()
    with socket.create_connection(("127.0.0.1", srv.port), timeout=10.0) as sock:
        sent = time.monotonic()
        sock.sendall(request)
        reply = b""
        while b"\r\n" not in reply:
            chunk = sock.recv(4096)
            assert chunk, "the connection closed without an answer"
            reply += chunk
    return sent, int(reply.split(b" ", 2)[1])


def _first_zero_after(emu: EmulatorProcess, t: float) -> float | None:
    return next((at for at, v in emu.torques_since(t) if v == 0.0), None)


def _driving(emu: EmulatorProcess, since: float) -> bool:
    return sum(v != 0.0 for _, v in emu.torques_since(since)) >= 50


def test_an_estop_request_zeroes_the_device_within_the_bound(
    rig: tuple[ServerProcess, EmulatorProcess],
) -> None:
    srv, emu = rig
    with srv.client("trainer") as c:
        uid = c.post("/api/v1/users", json={"name": "Timed"}).json()["id"]
        began = time.monotonic()
        r = c.post("/api/v1/sessions", json={"user_id": uid, "duration": 60.0})
        assert r.status_code == 201, r.text
        sid = r.json()["id"]
        assert wait_for(lambda: _driving(emu, began), timeout=15.0)
        sent, status = _estop(srv, srv.token("trainer"))
        assert status == 202
        assert wait_for(lambda: _first_zero_after(emu, sent) is not None, timeout=5.0)
        zero = _first_zero_after(emu, sent)
        assert zero is not None and zero - sent < ZERO_WITHIN, f"{1e3 * (zero - sent):.1f} ms"
        body = srv.wait_status(sid, {"stopped", "aborted", "faulted", "completed"}, 20.0)
        assert body["session"]["status"] == "stopped", body["session"]
        assert all(v == 0.0 for _, v in emu.torques_since(zero))  # nothing after the zero
        snap = emu.snapshot()
        assert snap.applied_torque == 0.0 and snap.current_state == 1
        assert c.get("/api/v1/machine").json()["state"] == "estopped"  # latched
        assert c.post("/api/v1/machine/reset").status_code == 202
        # a reset never starts motion: the axis stays idle, no torque reaches the device
        reset_at = time.monotonic()
        assert wait_for(lambda: c.get("/api/v1/machine").json()["state"] == "idle", 5.0)
        assert emu.snapshot().current_state == 1
        assert all(v == 0.0 for _, v in emu.torques_since(reset_at))
