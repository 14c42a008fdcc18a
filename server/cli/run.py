"""``ergoseek run SCENARIO.toml [--machine sim|odrive --device PATH]``: one live session.

The session runs in the real-time worker process against the chosen machine: the simulator
(paced in real time) or an ODrive on a serial device (for instance the one
``ergoseek emulate-odrive`` prints). Progress is printed once a second, seeker evaluations as
they happen, the summary and the loop timing at the end. Ctrl-C (SIGINT) or SIGTERM stops
the session at once (zero torque; status ``stopped``), its summary printed. Exit status:
0 completed, 1 aborted or faulted (or the machine refused to arm: one line on stderr says why,
e.g. an uncalibrated axis, a wrong axis, an unsupported firmware, a drive setting that defeats
a limit), 2 bad input, 130 stopped by Ctrl-C, 143 by SIGTERM.

A signal is noted by a handler and acted on by the follow loop, between two reads of the
worker's events: never an exception in the middle of one. Started with SIGINT ignored (a
background job of a shell without job control, ``nohup``), Ctrl-C stays ignored, as such a
job's should; SIGTERM still stops it.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import signal
import sys
import time
from typing import Any

# The drive's settings, as flags: MachineSpec's fields (its defaults apply when not given).
DRIVE_FLAGS: tuple[tuple[str, type, tuple[int | str, ...] | None, str], ...] = (
    ("--baudrate", int, None, "odrive: UART baud rate (default 115200; USB ignores it)"),
    ("--gear-ratio", float, None, "odrive: motor turns per handle turn"),
    ("--direction", int, (1, -1), "odrive: +1 or -1"),
    ("--torque-constant", float, None, "odrive: the motor's torque constant, N·m/A (8.27/Kv)"),
    ("--vel-limit-tolerance", float, None, "odrive: overspeed trips at this × vel_limit"),
    ("--firmware-policy", str, ("supported", "probe"), "odrive: which firmware to accept"),
    ("--watchdog-timeout", float, None, "odrive: device watchdog, s"),
    ("--reply-timeout", float, None, "odrive: longest wait for a reply, s"),
)


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
    for flag, kind, choices, text in DRIVE_FLAGS:
        p.add_argument(flag, type=kind, choices=choices, help=text)
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
    drive = {
        name: value
        for name in (flag.removeprefix("--").replace("-", "_") for flag, *_ in DRIVE_FLAGS)
        if (value := getattr(args, name)) is not None
    }
    try:
        return MachineSpec(
            kind=args.machine, device=args.device if args.machine == "odrive" else None, **drive
        )
    except ValidationError as exc:
        raise UsageError(describe_validation_error(exc)) from None


class Signals:
    """SIGINT and SIGTERM, noted while the session runs (the first one; later ones are the
    same request). The previous handlers are put back on exit."""

    def __init__(self) -> None:
        self.received: signal.Signals | None = None
        self._previous: dict[signal.Signals, Any] = {}

    def __enter__(self) -> Signals:
        for sig in (signal.SIGINT, signal.SIGTERM):
            if sig == signal.SIGINT and signal.getsignal(sig) == signal.SIG_IGN:
                continue  # ignored by whoever started it: Ctrl-C is not this job's
            self._previous[sig] = signal.signal(sig, self._note)
        return self

    def _note(self, signum: int, _frame: object) -> None:
        self.received = self.received or signal.Signals(signum)

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)

    @property
    def exit_status(self) -> int:
        """128 + the signal's number: what a shell reports for a job the signal ended."""
        return 128 + int(self.received or 0)


# the session's reason for each (None: the worker's own, "stopped at once by the operator");
# a SIGTERM to the whole process group reaches the worker too, which ends it aborted,
# "terminated (SIGTERM)", on its own
STOP_REASONS = {signal.SIGINT: None, signal.SIGTERM: "terminated (SIGTERM)"}


def _fmt(x: float, spec: str = ".2f") -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, spec)


def run(args: argparse.Namespace) -> int:
    from server.cli import UsageError
    from sessions.config import load_scenario
    from sessions.machine import check_controller
    from sessions.worker import Worker, WorkerOptions

    cfg = load_scenario(args.scenario)
    spec = _machine_spec(args)
    try:
        check_controller(spec.kind, spec.has_torque_sensor, cfg.controller.kind)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    options = WorkerOptions(cpu=args.cpu, realtime=not args.no_realtime)
    say = (lambda *a: None) if (args.quiet or args.json) else print
    with Signals() as signals, Worker(spec, options) as worker:
        ready = worker.start()
        assert ready is not None
        if ready.fault:
            print(f"ergoseek run: machine fault: {ready.fault}", file=sys.stderr)
            return 1
        if signals.received is not None:  # before any session: nothing to stop
            return signals.exit_status
        rt = ready.realtime
        say(
            f"worker pid {ready.pid}: {spec.kind} machine, {cfg.rate:g} Hz, "
            f"{'SCHED_FIFO' if rt.sched_fifo else 'SCHED_OTHER'}"
            + (f", CPU {rt.cpu}" if rt.cpu is not None else "")
            + "".join(f"; {n}" for n in rt.notes)
        )
        end, refused = _follow(worker, cfg, say, signals)
    if refused is not None:
        print(f"ergoseek run: the machine refused the session: {refused}", file=sys.stderr)
        return 1
    if end is None:
        print("ergoseek run: the session did not report its end", file=sys.stderr)
        return 1
    _report(end, ready, args.json)
    if signals.received is not None:
        return signals.exit_status
    return 0 if end.status == "completed" else 1


def _follow(worker: Any, cfg: Any, say: Any, signals: Signals) -> tuple[Any, str | None]:
    """Run the session to its end, saying what happens; (its SessionEnded, why it never
    started: the machine refused to arm, or the worker was lost first). A signal stops it at
    once and waits (bounded) for its end."""
    from sessions.worker import WorkerError

    reader = worker.open_reader()
    worker.start_session(cfg, f"run-{os.getpid()}")
    end = None
    next_line = time.monotonic() + 1.0
    stop_by: float | None = None  # when a signal's stop gives up waiting for the end
    try:
        while end is None:
            if signals.received is not None and stop_by is None:
                # (a worker that took the group's signal first is gone: its end is polled)
                with contextlib.suppress(WorkerError):
                    worker.stop(immediate=True, reason=STOP_REASONS[signals.received])
                stop_by = time.monotonic() + 5.0
            if stop_by is not None and time.monotonic() > stop_by:
                return None, None
            for ev in worker.poll():
                if ev.kind == "session_ended":
                    end = ev
                elif (ev.kind == "rejected" and ev.command == "start") or (
                    ev.kind == "lost" and end is None
                ):
                    return None, ev.reason
                else:
                    _say_event(ev, say)
            batch = reader.read()
            now = time.monotonic()
            if len(batch) and now >= next_line:
                next_line += 1.0
                _say_progress(batch.data[-1], worker.status().timing, say)
            time.sleep(0.01 if stop_by is not None else 0.02)
    finally:
        reader.close()
    return end, None


def _say_event(ev: Any, say: Any) -> None:
    if ev.kind == "evaluation":
        say(
            f"  evaluation  t = {ev.session_t:6.1f} s  γ = {ev.candidate:.3f} "
            f"rad/s  p = {ev.power:.3f} W  → next {ev.target:.3f}" + ("  (done)" if ev.done else "")
        )
    elif ev.kind in ("rejected", "fault", "stopping", "limit", "lost"):
        say(f"  {ev.kind}: " + ", ".join(
            f"{k} = {v}" for k, v in ev.to_dict().items() if k not in ("kind", "t")
        ))  # fmt: skip


def _say_progress(r: Any, timing: Any, say: Any) -> None:
    """Once a second: the newest record, and the loop's lateness so far."""
    from sessions.worker.ring import INDEX

    say(
        f"t = {r[INDEX['t']]:6.1f} s  w = {_fmt(r[INDEX['w']])}  "
        f"wd = {_fmt(r[INDEX['wd']])} rad/s  u = {_fmt(r[INDEX['u_out']])} N·m  "
        f"p = {_fmt(r[INDEX['p']])} W  W = {_fmt(r[INDEX['W']], '.1f')} J  "
        f"γ = {_fmt(r[INDEX['gamma']])}"
        + (f"  late p99 {timing.p99_us:.0f} µs, missed {timing.missed}" if timing else "")
    )


def _report(end: Any, ready: Any, as_json: bool) -> None:
    summary, timing = end.summary, end.timing
    if as_json:
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
        return
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
