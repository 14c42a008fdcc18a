"""``ergoseek run SCENARIO.toml [--machine sim|odrive --device PATH]``: one live session.

The session runs in the real-time worker process against the chosen machine: the simulator
(paced in real time) or an ODrive on a serial device (for instance the one
``ergoseek emulate-odrive`` prints). Progress is printed once a second, seeker evaluations as
they happen, the summary and the loop timing at the end. Ctrl-C stops the session at once
(zero torque; status ``stopped``). Exit status: 0 completed, 1 aborted or faulted, 2 bad input,
130 stopped by Ctrl-C.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from typing import Any


def register(sub: Any) -> None:
    p = sub.add_parser(
        "run",
        help="run one session live, in the real-time worker (simulator or ODrive)",
        description="Run a TOML scenario live: the real-time worker drives the machine at the "
        "scenario's loop rate. Ctrl-C stops with zero torque.",
    )
    p.add_argument("scenario", help="TOML scenario file (see scenarios/)")
    p.add_argument("--machine", choices=("sim", "odrive"), default="sim")
    p.add_argument("--device", metavar="PATH", help="odrive: serial device (e.g. /dev/ttyACM0)")
    p.add_argument("--baudrate", type=int, default=921600, help="odrive: UART baud rate")
    p.add_argument(
        "--gear-ratio", type=float, default=1.0, help="odrive: motor turns per handle turn"
    )
    p.add_argument("--direction", type=int, choices=(1, -1), default=1, help="odrive: +1 or -1")
    p.add_argument(
        "--watchdog-timeout", type=float, default=0.05, help="odrive: device watchdog, s"
    )
    p.add_argument(
        "--reply-timeout", type=float, default=0.02, help="odrive: longest wait for a reply, s"
    )
    p.add_argument("--cpu", type=int, help="pin the worker to this CPU")
    p.add_argument("--no-realtime", action="store_true", help="do not ask for SCHED_FIFO")
    p.add_argument("--json", action="store_true", help="print one JSON object at the end")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(run=run)


def _machine_spec(args: argparse.Namespace) -> Any:
    from pydantic import ValidationError

    from server.cli import UsageError
    from sessions.config import describe_validation_error
    from sessions.machine import MachineSpec

    if args.machine == "odrive":
        if not args.device:
            raise UsageError("--machine odrive needs --device PATH")
        if not os.path.exists(args.device):
            raise UsageError(f"{args.device}: no such device")
    try:
        return MachineSpec(
            kind=args.machine,
            device=args.device if args.machine == "odrive" else None,
            baudrate=args.baudrate,
            gear_ratio=args.gear_ratio,
            direction=args.direction,
            watchdog_timeout=args.watchdog_timeout,
            reply_timeout=args.reply_timeout,
        )
    except ValidationError as exc:
        raise UsageError(describe_validation_error(exc)) from None


def _fmt(x: float, spec: str = ".2f") -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, spec)


def run(args: argparse.Namespace) -> int:
    from server.cli import UsageError
    from sessions.config import load_scenario
    from sessions.worker import Worker, WorkerOptions
    from sessions.worker.ring import INDEX

    cfg = load_scenario(args.scenario)
    spec = _machine_spec(args)
    if cfg.controller.kind == "measured" and not spec.has_torque_sensor:
        raise UsageError(
            "controller 'measured' (eq. 7) needs a torque sensor; the odrive machine has none "
            "(use controller.kind = 'rise')"
        )
    options = WorkerOptions(cpu=args.cpu, realtime=not args.no_realtime)
    say = (lambda *a: None) if (args.quiet or args.json) else print
    with Worker(spec, options) as worker:
        ready = worker.start()
        assert ready is not None
        if ready.fault:
            print(f"ergoseek run: machine fault: {ready.fault}", file=sys.stderr)
            return 1
        rt = ready.realtime
        say(
            f"worker pid {ready.pid}: {spec.kind} machine, {cfg.rate:g} Hz, "
            f"{'SCHED_FIFO' if rt.sched_fifo else 'SCHED_OTHER'}"
            + (f", CPU {rt.cpu}" if rt.cpu is not None else "")
            + "".join(f"; {n}" for n in rt.notes)
        )
        reader = worker.open_reader()
        worker.start_session(cfg, f"run-{os.getpid()}")
        end = None
        interrupted = False
        next_line = time.monotonic() + 1.0
        try:
            while end is None:
                for ev in worker.poll():
                    if ev.kind == "session_ended":
                        end = ev
                    elif ev.kind == "evaluation":
                        say(
                            f"  evaluation  t = {ev.session_t:6.1f} s  γ = {ev.candidate:.3f} "
                            f"rad/s  p = {ev.power:.3f} W  → next {ev.target:.3f}"
                            + ("  (done)" if ev.done else "")
                        )
                    elif ev.kind in ("rejected", "fault", "stopping", "limit", "lost"):
                        say(f"  {ev.kind}: " + ", ".join(
                            f"{k} = {v}" for k, v in ev.to_dict().items() if k not in ("kind", "t")
                        ))  # fmt: skip
                batch = reader.read()
                now = time.monotonic()
                if len(batch) and now >= next_line:
                    next_line += 1.0
                    r = batch.data[-1]
                    timing = worker.status().timing
                    say(
                        f"t = {r[INDEX['t']]:6.1f} s  w = {_fmt(r[INDEX['w']])}  "
                        f"wd = {_fmt(r[INDEX['wd']])} rad/s  u = {_fmt(r[INDEX['u_out']])} N·m  "
                        f"p = {_fmt(r[INDEX['p']])} W  W = {_fmt(r[INDEX['W']], '.1f')} J  "
                        f"γ = {_fmt(r[INDEX['gamma']])}"
                        + (
                            f"  late p99 {timing.p99_us:.0f} µs, missed {timing.missed}"
                            if timing
                            else ""
                        )
                    )
                time.sleep(0.02)
        except KeyboardInterrupt:
            interrupted = True
            worker.stop(immediate=True)
            deadline = time.monotonic() + 5.0
            while end is None and time.monotonic() < deadline:
                for ev in worker.poll():
                    if ev.kind == "session_ended":
                        end = ev
                time.sleep(0.01)
        finally:
            reader.close()
    if end is None:
        print("ergoseek run: the session did not report its end", file=sys.stderr)
        return 1
    summary, timing = end.summary, end.timing
    if args.json:
        print(
            json.dumps(
                {
                    "status": end.status,
                    "reason": end.reason,
                    "summary": summary.model_dump(),
                    "timing": end.to_dict()["timing"],
                    "realtime": ready.to_dict()["realtime"],
                }
            )
        )
    else:
        opt = "-" if summary.optimum_w is None else f"{summary.optimum_w:.3f} rad/s"
        print(f"session {end.status}: {end.reason}")
        print(
            f"  optimum {opt}  (p = {_fmt(summary.optimum_p, '.3f')} W, "
            f"{summary.evaluations} evaluations, {'converged' if summary.converged else 'open'})"
        )
        print(
            f"  mean power {summary.mean_power:.2f} W  peak {summary.peak_power:.2f} W  "
            f"W = {summary.work:.1f} J  W_min = {summary.passivity_min:.2f} J  "
            f"{summary.duration:.1f} s"
        )
        print(
            f"  loop {timing.rate_hz:g} Hz: lateness p50/p99/p99.9/max = {timing.p50_us:.0f}/"
            f"{timing.p99_us:.0f}/{timing.p999_us:.0f}/{timing.max_us:.0f} µs, missed "
            f"{timing.missed} ({timing.missed_ratio:.3%}), "
            f"compute p99 {timing.compute_p99_us:.0f} µs"
        )
    if interrupted:
        return 130
    return 0 if end.status == "completed" else 1
