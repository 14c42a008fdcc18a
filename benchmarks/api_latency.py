"""REST latency of the calls a trainer makes: start, stop, status, a telemetry page.

    python benchmarks/api_latency.py [--rounds 20] [--json]

A real server with the simulated machine, one client over HTTP/1.1 keep-alive. Start and stop
are timed on real sessions (stop waits for nothing: it is accepted, the ramp-out follows);
status is GET /api/v1/machine; the telemetry page is 2000 decimated points of a stored
60 s session.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np
from _server import start_server


def pct(xs: list[float]) -> dict[str, float]:
    ms = np.array(xs) * 1e3
    return {
        "p50_ms": round(float(np.percentile(ms, 50)), 2),
        "p95_ms": round(float(np.percentile(ms, 95)), 2),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    srv = start_server()
    timings: dict[str, list[float]] = {"start": [], "stop": [], "status": [], "telemetry_page": []}
    try:
        with srv.client("trainer") as c:
            uid = c.post("/api/v1/users", json={"name": "bench"}).json()["id"]
            stored = c.post("/api/v1/sessions", json={"user_id": uid, "duration": 60}).json()["id"]
            srv.wait_status(stored, {"completed"}, 90)
            for _ in range(args.rounds):
                t0 = time.perf_counter()
                r = c.post("/api/v1/sessions", json={"user_id": uid, "duration": 60})
                timings["start"].append(time.perf_counter() - t0)
                assert r.status_code == 201, r.text
                sid = r.json()["id"]
                time.sleep(0.3)
                t0 = time.perf_counter()
                assert c.post(f"/api/v1/sessions/{sid}/stop").status_code == 202
                timings["stop"].append(time.perf_counter() - t0)
                srv.wait_status(sid, {"stopped"}, 10)
            for _ in range(args.rounds * 10):
                t0 = time.perf_counter()
                c.get("/api/v1/machine").raise_for_status()
                timings["status"].append(time.perf_counter() - t0)
            for _ in range(args.rounds * 2):
                t0 = time.perf_counter()
                c.get(
                    f"/api/v1/sessions/{stored}/telemetry", params={"points": 2000}
                ).raise_for_status()
                timings["telemetry_page"].append(time.perf_counter() - t0)
    finally:
        srv.stop()
    out = {k: pct(v) for k, v in timings.items()}
    out["loadavg_1min"] = [round(load0, 2), round(os.getloadavg()[0], 2)]
    print(json.dumps(out) if args.json else json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
