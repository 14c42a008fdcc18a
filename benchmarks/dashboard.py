"""What the dashboard costs: the web process's CPU with 0, 1 and 5 dashboards open in headless
Chromium pages while a session runs, how long a page takes to show its first chart frame,
and the worker's loop lateness with 5 dashboards open.

    python benchmarks/dashboard.py [--seconds 10] [--json]

Runs ``ergoseek demo`` (simulated machine) in its own process with a fresh data directory,
starts a session for the demo user Ada, and opens trainer dashboards in Debian's Chromium.

- ``web_cpu_share_N``: CPU time of the web process (all its threads: uvicorn, the proxy, the
  feed, both viser servers; not the worker, not the browser) over ``--seconds`` of wall time
  with N dashboards open, as a fraction of one core; ``web_cpu_share_no_dashboard``: the same
  with the dashboard switched off (``--no-dashboard``), for reference.
- ``frames_per_s``: WebSocket frames (batches of viser updates) per second that reach one
  dashboard client through the proxy.
- ``first_frame_s``: from navigating to ``/dashboard/`` (already logged in) to the first live
  chart frame on the page (the live readout that comes with each chart frame shows data).
- ``loop_p99_us_with_0`` / ``loop_p99_us_with_5``: the worker's wake-up lateness p99
  (``/api/v1/machine`` timing) over a session run with 0 / 5 dashboards open (``missed_*``:
  whole periods skipped, ``steal_*``: the share of CPU time the hypervisor took meanwhile —
  on a shared VM it, not the dashboard, often sets the worker's lateness); ``*_niced``: the
  same with the browsers at nice 19.

Chromium renders WebGL in software here, so five pages load the machine's two cores heavily;
``load_1min`` and ``cpus`` give the context.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from _server import cpu_seconds  # (first: it puts the checkout on sys.path)

from testing.browser import TRAINER, VIEWPORT, DemoServer, chromium, login

ADA = 1  # the first demo user: a Hill user, τ0 = 3 N·m, wmax = 10 rad/s


def web_cpu_share(pid: int, seconds: float) -> float:
    c0, t0 = cpu_seconds(pid), time.monotonic()
    time.sleep(seconds)
    return (cpu_seconds(pid) - c0) / (time.monotonic() - t0)


def start_session(api: Any, duration: float) -> int:
    r = api.post("/api/v1/sessions", json={"user_id": ADA, "duration": duration})
    r.raise_for_status()
    return int(r.json()["id"])


def stop_session(api: Any, session_id: int) -> None:
    api.post(f"/api/v1/sessions/{session_id}/stop")
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        if api.get("/api/v1/machine").json()["state"] == "idle":
            return
        time.sleep(0.2)
    raise TimeoutError("the machine did not come back to idle")


def cpu_times() -> list[int]:
    with open("/proc/stat") as f:
        return [int(v) for v in f.readline().split()[1:]]


def steal_share(before: list[int], after: list[int]) -> float:
    """The share of CPU time the hypervisor took from this VM between two /proc/stat reads."""
    delta = [b - a for a, b in zip(before, after, strict=True)]
    return round(delta[7] / sum(delta), 4) if len(delta) > 7 and sum(delta) else 0.0


def loop_p99(api: Any, session_id: int, seconds: float) -> float:
    """Lateness p99 of a session after ``seconds`` (the worker's stats since its start)."""
    time.sleep(seconds)
    timing = api.get("/api/v1/machine").json()["timing"] or {}
    assert api.get("/api/v1/machine").json()["session_id"] == session_id
    return float(timing.get("p99_us", float("nan")))


def frames_per_s(server: DemoServer, api: Any, seconds: float) -> float:
    """viser updates per second that reach a client through the proxy (a Python WebSocket
    client logged in as the trainer; viser's page runs its socket in a Web Worker)."""
    import viser
    from websockets.sync.client import connect

    cookie = api.cookies.get("ergoseek_session")
    headers = {"Cookie": f"ergoseek_session={cookie}", "Origin": server.url}
    subprotocol = f"viser-v{viser.__version__}"
    with connect(
        server.ws_url + "/dashboard",
        subprotocols=[subprotocol],  # type: ignore[list-item]
        additional_headers=headers,
        max_size=2**26,
    ) as ws:
        ws.recv(timeout=10)  # the initial state
        count, started = 0, time.monotonic()
        while time.monotonic() - started < seconds:
            ws.recv(timeout=10)
            count += 1
        return count / (time.monotonic() - started)


def first_frame(page: Any, url: str) -> float:
    started = time.monotonic()
    page.goto(url + "/dashboard/")
    page.wait_for_function(
        "() => [...document.querySelectorAll('p')].some(p => /t = \\d/.test(p.textContent))",
        timeout=60_000,
        polling=20,
    )
    return time.monotonic() - started


def baseline(seconds: float) -> float:
    """The web process's CPU share with a session running and the dashboard switched off."""
    with (
        tempfile.TemporaryDirectory() as tmp,
        DemoServer(Path(tmp), args=["--no-dashboard"]) as server,
        server.client() as api,
    ):
        session = start_session(api, 600.0)
        time.sleep(2.0)
        share = web_cpu_share(server.pid, seconds)
        stop_session(api, session)
    return share


def open_dashboards(browser: Any, server: DemoServer, n: int) -> tuple[Any, list[Any], float]:
    """A logged-in context with ``n`` dashboard pages showing live data; the first page's
    time to its first chart frame."""
    context = browser.new_context(viewport=VIEWPORT)
    first = context.new_page()
    login(first, server.url, TRAINER, server.password)
    first_s = first_frame(first, server.url)
    pages = [first]
    for _ in range(n - 1):
        page = context.new_page()
        first_frame(page, server.url)
        pages.append(page)
    return context, pages, first_s


def restart_session(api: Any, session: int, seconds: float) -> tuple[int, float, int, float]:
    """A fresh session (its timing stats start at zero): (id, lateness p99, missed periods,
    CPU steal meanwhile)."""
    stop_session(api, session)
    session = start_session(api, 600.0)
    before = cpu_times()
    p99 = loop_p99(api, session, seconds)
    steal = steal_share(before, cpu_times())
    missed = (api.get("/api/v1/machine").json()["timing"] or {}).get("missed")
    return session, p99, missed, steal


def run(seconds: float) -> dict[str, Any]:
    out: dict[str, Any] = {"seconds": seconds, "cpus": os.cpu_count()}
    out["web_cpu_share_no_dashboard"] = round(baseline(seconds), 4)
    with tempfile.TemporaryDirectory() as tmp, DemoServer(Path(tmp)) as server:
        pid = server.pid
        with server.client() as api:
            session = start_session(api, 600.0)
            time.sleep(2.0)
            out["web_cpu_share_0"] = round(web_cpu_share(pid, seconds), 4)
            session, p99, missed, steal = restart_session(api, session, 2 * seconds)
            out["loop_p99_us_with_0"] = round(p99, 1)
            out["missed_with_0"], out["steal_with_0"] = missed, steal
            out["frames_per_s"] = round(frames_per_s(server, api, 5.0), 1)
            with chromium() as browser:
                context, _pages, first_s = open_dashboards(browser, server, 1)
                out["first_frame_s"] = round(first_s, 3)
                time.sleep(2.0)
                out["web_cpu_share_1"] = round(web_cpu_share(pid, seconds), 4)
                context.close()
                context, _pages, _ = open_dashboards(browser, server, 5)
                time.sleep(3.0)
                out["web_cpu_share_5"] = round(web_cpu_share(pid, seconds), 4)
                session, p99, missed, steal = restart_session(api, session, 2 * seconds)
                out["loop_p99_us_with_5"] = round(p99, 1)
                out["missed_with_5"], out["steal_with_5"] = missed, steal
                out["load_1min"] = round(os.getloadavg()[0], 2)
                context.close()
            # The same with the browsers at nice 19 (as if they ran elsewhere, mostly).
            with chromium(nice=19) as browser:
                context, _pages, _ = open_dashboards(browser, server, 5)
                time.sleep(3.0)
                session, p99, missed, steal = restart_session(api, session, 2 * seconds)
                out["loop_p99_us_with_5_niced"] = round(p99, 1)
                out["missed_with_5_niced"], out["steal_with_5_niced"] = missed, steal
                context.close()
            stop_session(api, session)
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=10.0, help="each CPU measurement, s")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    args = p.parse_args()
    result = run(args.seconds)
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:22s} {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
