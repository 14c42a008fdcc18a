"""Live telemetry to N WebSocket clients at 30 Hz: latency, and what it costs the loop.

    python benchmarks/live_fanout.py [--clients 20] [--seconds 20] [--json]

Runs a real server with the simulated machine. First a session with no client (the loop's
lateness alone), then the same with N clients each asking 30 Hz. Latency is per sample: the
sample's monotonic time in the worker's loop → the client's monotonic clock when its frame
arrived (one machine, one CLOCK_MONOTONIC). server_cpu_share is the web process's CPU time
over the wall time while the clients are connected.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import time

import numpy as np
import websockets
from _server import cpu_seconds, peak_rss_mb, start_server


def session(srv, seconds: float) -> dict:  # type: ignore[no-untyped-def]
    with srv.client("trainer") as c:
        uid = c.post("/api/v1/users", json={"name": f"bench-{time.monotonic()}"}).json()["id"]
        sid = c.post("/api/v1/sessions", json={"user_id": uid, "duration": seconds}).json()["id"]
    return {"sid": sid}


def finished_timing(srv, sid: int, seconds: float) -> dict:  # type: ignore[no-untyped-def]
    srv.wait_status(sid, {"completed", "stopped", "aborted"}, seconds + 30)
    with srv.client("viewer") as c:
        return c.get("/api/v1/machine").json()["timing"]


async def client(url: str, headers: dict, stop: float, lat: list[float], frames: list[int]) -> None:
    async with websockets.connect(url, additional_headers=headers, max_size=None) as ws:
        while time.monotonic() < stop:
            try:
                msg = await asyncio.wait_for(ws.recv(), timeout=max(0.01, stop - time.monotonic()))
            except TimeoutError:
                break
            now = time.monotonic()
            frame = json.loads(msg)
            if frame.get("type") == "telemetry":
                frames.append(len(frame["mono"]))
                lat.extend(now - m for m in frame["mono"] if m is not None)


async def fan_out(srv, n: int, seconds: float) -> tuple[list[float], list[int]]:  # type: ignore[no-untyped-def]
    url = f"{srv.ws_url}/api/v1/live?rate=30"
    headers = srv.headers("viewer")
    lat: list[float] = []
    frames: list[int] = []
    stop = time.monotonic() + seconds
    await asyncio.gather(*(client(url, headers, stop, lat, frames) for _ in range(n)))
    return lat, frames


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clients", type=int, default=20)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    srv = start_server()
    try:
        alone = session(srv, args.seconds)
        t_alone = finished_timing(srv, alone["sid"], args.seconds)
        busy = session(srv, args.seconds + 5)
        time.sleep(1.0)
        cpu0, wall0 = cpu_seconds(srv.proc.pid), time.monotonic()
        lat, frames = asyncio.run(fan_out(srv, args.clients, args.seconds))
        cpu1, wall1 = cpu_seconds(srv.proc.pid), time.monotonic()
        t_busy = finished_timing(srv, busy["sid"], args.seconds + 5)
        rss = peak_rss_mb(srv.proc.pid)
    finally:
        srv.stop()
    ms = np.array(lat) * 1e3
    out = {
        "clients": args.clients,
        "seconds": args.seconds,
        "frames_per_client_per_s": round(len(frames) / args.clients / args.seconds, 1),
        "latency_p50_ms": round(float(np.percentile(ms, 50)), 2),
        "latency_p95_ms": round(float(np.percentile(ms, 95)), 2),
        "latency_max_ms": round(float(ms.max()), 2),
        "loop_p99_us_alone": t_alone["p99_us"],
        "loop_p99_us_with_clients": t_busy["p99_us"],
        "missed_ratio_alone": t_alone["missed_ratio"],
        "missed_ratio_with_clients": t_busy["missed_ratio"],
        "server_cpu_share": round((cpu1 - cpu0) / (wall1 - wall0), 3),
        "server_peak_rss_mb": rss,
        "loadavg_1min": [round(load0, 2), round(os.getloadavg()[0], 2)],
    }
    print(json.dumps(out) if args.json else json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
