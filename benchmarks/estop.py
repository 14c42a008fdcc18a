"""REST e-stop latency: ``POST /api/v1/machine/estop`` → the first zero-torque sample in the ring,
idle, with live clients, and under a flood of big bodies and garbage.

    python benchmarks/estop.py [--trials 40] [--clients 20] [--flood-rate 200] [--json]

A real server (simulated machine). Each trial starts a session, lets it run 0.2–0.5 s, then
sends the e-stop on a new connection (accept, parse, login check, the worker's pipe) and
takes the time just before the request's first byte. The end of the measurement is the
e-stop's own record in the ring: the worker stamps every record with its CLOCK_MONOTONIC
(``mono``), and the record flagged e-stop is the one that wrote zero torque; a live client
(rate 30, which always keeps zero-torque records) hands it over. One machine, one clock, so
latency = mono(record) − t(request); how fast the record then reaches a browser is not in it.

Conditions, in order: **idle**; **clients**: ``--clients`` more live WebSocket clients at
``--live-rate`` (their own process); **flood**: the clients, plus another process that for the
whole phase sends ``--flood-rate`` requests a second of garbage (not HTTP, TLS on plain HTTP,
huge request lines, bad JSON, forged tokens, wrong passwords, a foreign Host) and streams
``--body-mb`` MB bodies (announced, and chunked) at ``--bodies`` a second, all on loopback,
bounded in time and count. The machine's load is reported with the figures.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import multiprocessing as mp
import os
import queue
import random
import socket
import threading
import time
from collections.abc import Iterator
from typing import Any

import httpx
import numpy as np
from _server import ServerProcess, peak_rss_mb, start_server
from websockets.sync.client import connect

from sessions.codes import FLAG_ESTOP
from testing.flood import flood, request_head


class EStopWatcher:
    """A live client that hands over the ``mono`` of every e-stop record it sees."""

    def __init__(self, srv: ServerProcess) -> None:
        self.rows: queue.Queue[float] = queue.Queue()
        self.finished: queue.Queue[int] = queue.Queue()
        self._ws = connect(
            f"{srv.ws_url}/api/v1/live?rate=30", additional_headers=srv.headers("viewer")
        )
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        with contextlib.suppress(Exception):
            for msg in self._ws:
                frame = json.loads(msg)
                if frame.get("type") == "telemetry":
                    for flags, mono in zip(frame["flags"], frame["mono"], strict=True):
                        if int(flags) & FLAG_ESTOP:
                            self.rows.put(mono)
                elif frame.get("type") == "session_finished":
                    self.finished.put(frame["session_id"])

    def close(self) -> None:
        self._ws.close()


def _drain(q: queue.Queue[Any]) -> None:
    with contextlib.suppress(queue.Empty):
        while True:
            q.get_nowait()


def trial(srv: ServerProcess, watch: EStopWatcher, c: httpx.Client, uid: int) -> dict[str, float]:
    """One session, one e-stop: (request → zero-torque record, request → 202) in s."""
    for _ in range(50):
        r = c.post("/api/v1/sessions", json={"user_id": uid, "duration": 60})
        if r.status_code == 201:
            break
        c.post("/api/v1/machine/reset")
        time.sleep(0.1)
    r.raise_for_status()
    sid = r.json()["id"]
    time.sleep(random.uniform(0.2, 0.5))
    _drain(watch.rows)
    request = request_head(
        "POST", "/api/v1/machine/estop", f"127.0.0.1:{srv.port}",
        {**srv.headers("trainer"), "Content-Length": "0"},
    )  # fmt: skip
    t0 = time.monotonic()  # then: a new connection, the request, its answer
    with socket.create_connection(("127.0.0.1", srv.port), timeout=10) as s:
        s.sendall(request)
        reply = s.recv(4096)
    answered = time.monotonic() - t0
    assert reply.startswith(b"HTTP/1.1 202"), reply
    zero = watch.rows.get(timeout=10) - t0
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:  # the session's end is stored before the next one
        with contextlib.suppress(queue.Empty):
            if watch.finished.get(timeout=0.5) == sid:
                break
    c.post("/api/v1/machine/reset").raise_for_status()
    return {"zero": zero, "reply": answered}


def _ordinary() -> None:
    """A load process runs at the ordinary priority, whatever the measuring one has."""
    with contextlib.suppress(OSError):
        os.setpriority(os.PRIO_PROCESS, 0, 0)


def _live_clients(url: str, headers: dict[str, str], n: int, stop: Any, counts: Any) -> None:
    import websockets

    _ordinary()

    async def one(i: int) -> None:
        async with websockets.connect(url, additional_headers=headers, max_size=None) as ws:
            while not stop.is_set():
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(ws.recv(), 0.5)
                    counts[i] += 1

    async def all_of_them() -> None:
        await asyncio.gather(*(one(i) for i in range(n)), return_exceptions=True)

    asyncio.run(all_of_them())


@contextlib.contextmanager
def live_clients(srv: ServerProcess, n: int, rate: float) -> Iterator[Any]:
    ctx = mp.get_context("spawn")
    stop, counts = ctx.Event(), ctx.Array("l", n)
    url = f"{srv.ws_url}/api/v1/live?rate={rate:g}"
    proc = ctx.Process(target=_live_clients, args=(url, srv.headers("viewer"), n, stop, counts))
    proc.start()
    time.sleep(2.0)  # connected
    try:
        yield counts
    finally:
        stop.set()
        proc.join(10)
        if proc.is_alive():
            proc.terminate()


def _flood(port: int, seconds: float, rate: float, bodies: float, mb: int, out: Any) -> None:
    _ordinary()
    out.put(flood(port, seconds, rate, bodies, mb))


@contextlib.contextmanager
def flooding(srv: ServerProcess, seconds: float, args: argparse.Namespace) -> Iterator[Any]:
    ctx = mp.get_context("spawn")
    out = ctx.Queue()
    a = (srv.port, seconds, args.flood_rate, args.bodies, args.body_mb, out)
    proc = ctx.Process(target=_flood, args=a)
    proc.start()
    time.sleep(1.0)  # under way
    result: dict[str, Any] = {}
    try:
        yield result
    finally:
        proc.join(seconds + 30)
        if proc.is_alive():
            proc.terminate()
        with contextlib.suppress(queue.Empty):
            result.update(out.get(timeout=5))


def figures(xs: list[float]) -> dict[str, float]:
    ms = np.array(xs) * 1e3
    return {
        "p50_ms": round(float(np.percentile(ms, 50)), 2),
        "p99_ms": round(float(np.percentile(ms, 99)), 2),
        "max_ms": round(float(ms.max()), 2),
    }


def phase(srv: ServerProcess, watch: EStopWatcher, uid: int, n: int) -> dict[str, Any]:
    rows: list[dict[str, float]] = []
    with srv.client("trainer") as c:
        for _ in range(n):
            rows.append(trial(srv, watch, c, uid))
    zero, reply = figures([r["zero"] for r in rows]), figures([r["reply"] for r in rows])
    return {"zero": zero, "reply": reply, "trials": n}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=40, help="e-stops per condition")
    ap.add_argument("--clients", type=int, default=20)
    ap.add_argument("--live-rate", type=float, default=30.0)
    ap.add_argument("--flood-rate", type=float, default=200.0, help="garbage requests/s")
    ap.add_argument("--bodies", type=float, default=4.0, help="big bodies/s")
    ap.add_argument("--body-mb", type=int, default=50)
    ap.add_argument(
        "--client-nice",
        type=int,
        default=None,
        help="the measuring client's niceness, set after the server started (the server and "
        "the load keep theirs): isolates the server's latency from a loaded VM's",
    )
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    loads = [os.getloadavg()]
    room = str(args.clients + 8)  # the live caps, with room for these clients
    srv = start_server(env={"ERGOSEEK_LIVE_MAX_PER_ACCOUNT": room, "ERGOSEEK_LIVE_MAX_TOTAL": room})
    out: dict[str, Any] = {}
    try:
        with srv.client("trainer") as c:
            uid = c.post("/api/v1/users", json={"name": "estop-bench"}).json()["id"]
        if args.client_nice is not None:
            os.setpriority(os.PRIO_PROCESS, 0, args.client_nice)
        out["client_nice"] = os.getpriority(os.PRIO_PROCESS, 0)
        watch = EStopWatcher(srv)
        out["idle"] = phase(srv, watch, uid, args.trials)
        loads.append(os.getloadavg())
        with live_clients(srv, args.clients, args.live_rate) as counts:
            out["clients"] = phase(srv, watch, uid, args.trials)
            loads.append(os.getloadavg())
            t0 = time.monotonic()
            with flooding(srv, 1.5 * args.trials, args) as flood_result:
                out["flood"] = phase(srv, watch, uid, args.trials)
            out["flood"]["seconds"] = round(time.monotonic() - t0, 1)
            out["flood"]["sent"] = flood_result
            loads.append(os.getloadavg())
            out["clients"]["frames_per_client"] = min(counts[:])
        watch.close()
        out["server_peak_rss_mb"] = peak_rss_mb(srv.pid)
    finally:
        srv.stop()
    result = {
        **{
            f"{k}_{m}_ms": out[k]["zero"][f"{m}_ms"]
            for k in ("idle", "clients", "flood")
            for m in ("p50", "p99", "max")
        },
        "target": {"p99_ms": 20, "max_ms": 50},
        "detail": out,
        "loadavg": [[round(x, 2) for x in la] for la in loads],
        "cpus": os.cpu_count(),
    }
    print(json.dumps(result) if args.json else json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
