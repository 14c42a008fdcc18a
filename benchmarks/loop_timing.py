"""How well the real-time worker keeps its deadlines: one live session on the sim backend.

    python benchmarks/loop_timing.py [--seconds 20] [--rate 1000] [--readers 4] [--hog] [--json]

Conditions: idle (the default), ``--readers N`` (N processes draining the telemetry ring at
``--reader-hz``, 30 by default, as dashboards would), ``--hog`` (a process spinning on another
CPU; the worker is pinned to the last CPU, the hog to the first). The session is the default
scenario (Hill user with noise and ripple, RISE, Brent) for ``--seconds``.

Prints one JSON object with ``--json``: ``rate_hz``, ``p50_us``, ``p99_us``, ``p999_us``,
``max_us`` (lateness of the cycle wake-ups behind their deadlines), ``missed_ratio`` (periods
skipped / periods due), ``compute_p99_us`` (wake-up to torque written and record published),
plus the conditions, what the readers saw, what the OS granted (SCHED_FIFO, pinning) and the
machine's load and CPU steal during the run.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import time

from sessions.config import parse_session_config
from sessions.worker import RingInfo, RingReader, Worker, WorkerOptions


def _reader(info: RingInfo, hz: float, stop: object, out: object, ready: object) -> None:
    r = RingReader(info, 0)  # from the ring's first record: every one is read or counted
    ready.release()  # type: ignore[attr-defined]
    got = missed = reads = 0
    period = 1.0 / hz
    nxt = time.monotonic()
    while not stop.is_set():  # type: ignore[attr-defined]
        b = r.read()
        got += len(b)
        missed += b.missed
        reads += 1
        nxt += period
        time.sleep(max(0.0, nxt - time.monotonic()))
    b = r.read()
    out.put((got + len(b), missed + b.missed, reads))  # type: ignore[attr-defined]
    r.close()


def _hog(stop: object, cpu: int | None) -> None:
    if cpu is not None:
        os.sched_setaffinity(0, {cpu})
    x = 0
    while not stop.is_set():  # type: ignore[attr-defined]
        for i in range(100_000):
            x += i * i
    del x


def _cpu_times() -> list[int]:
    with open("/proc/stat") as f:
        return [int(v) for v in f.readline().split()[1:]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--readers", type=int, default=0, help="ring readers in other processes")
    ap.add_argument("--reader-hz", type=float, default=30.0)
    ap.add_argument("--hog", action="store_true", help="spin a process on another CPU")
    ap.add_argument("--cpu", type=int, help="pin the worker (default: last CPU with --hog)")
    ap.add_argument("--spin-us", type=float, default=WorkerOptions().spin_us)
    ap.add_argument("--no-realtime", action="store_true", help="do not ask for SCHED_FIFO")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    cpus = sorted(os.sched_getaffinity(0))
    worker_cpu = args.cpu
    hog_cpu = None
    if args.hog and len(cpus) > 1:
        worker_cpu = cpus[-1] if worker_cpu is None else worker_cpu
        hog_cpu = next(c for c in cpus if c != worker_cpu)
    cfg = parse_session_config(
        {
            "duration": args.seconds,
            "rate": args.rate,
            "user": {"noise": 0.03, "ripple": 0.1, "fatigue_tau": 1800.0},
        }
    )
    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    results = ctx.Queue()
    ready_sem = ctx.Semaphore(0)
    options = WorkerOptions(cpu=worker_cpu, realtime=not args.no_realtime, spin_us=args.spin_us)
    procs = []
    with Worker(options=options) as worker:
        ready = worker.start()
        assert ready is not None
        for _ in range(args.readers):
            p = ctx.Process(
                target=_reader, args=(worker.ring_info, args.reader_hz, stop, results, ready_sem)
            )
            p.start()
            procs.append(p)
        for _ in range(args.readers):
            if not ready_sem.acquire(timeout=120):
                raise SystemExit("a ring reader did not start")
        if args.hog:
            p = ctx.Process(target=_hog, args=(stop, hog_cpu))
            p.start()
            procs.append(p)
        time.sleep(0.5)  # let the readers and the hog settle
        load0, cpu0 = os.getloadavg()[0], _cpu_times()
        worker.start_session(cfg, "loop-timing")
        end = None
        while end is None:
            for ev in worker.poll():
                if ev.kind == "session_ended":
                    end = ev
                elif ev.kind in ("rejected", "fault", "lost"):
                    raise SystemExit(f"session failed: {ev.to_dict()}")
            time.sleep(0.05)
        cpu1, load1 = _cpu_times(), os.getloadavg()[0]
        stop.set()
        seen = [results.get(timeout=30) for _ in range(args.readers)]
        for p in procs:
            p.join(10)
    t = end.timing
    delta = [b - a for a, b in zip(cpu0, cpu1, strict=False)]
    steal = delta[7] / sum(delta) if len(delta) > 7 and sum(delta) else 0.0
    out = {
        "rate_hz": t.rate_hz,
        "p50_us": t.p50_us,
        "p99_us": t.p99_us,
        "p999_us": t.p999_us,
        "max_us": t.max_us,
        "missed_ratio": round(t.missed_ratio, 6),
        "compute_p99_us": t.compute_p99_us,
        "compute_p50_us": t.compute_p50_us,
        "cycles": t.cycles,
        "missed": t.missed,
        "seconds": args.seconds,
        "status": end.status,
        "readers": args.readers,
        "reader_hz": args.reader_hz if args.readers else None,
        "readers_records": [s[0] for s in seen],
        "readers_missed": [s[1] for s in seen],
        "hog": args.hog,
        "spin_us": args.spin_us,
        "sched_fifo": ready.realtime.sched_fifo,
        "cpu": ready.realtime.cpu,
        "hog_cpu": hog_cpu,
        "loadavg_1min": [round(load0, 2), round(load1, 2)],
        "cpu_steal": round(steal, 4),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S"),
    }
    if args.json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            print(f"{k:16s} {v}")


if __name__ == "__main__":
    main()
