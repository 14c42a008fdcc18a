"""The parent's handle on a worker process: what ``ergoseek run`` and the web server use.

Everything but :meth:`Worker.start` (waits for the worker to report ready) and
:meth:`Worker.shutdown` (waits, bounded, for it to exit) returns at once, so the handle is safe
to call from an asyncio event loop; run those two with ``await asyncio.to_thread(...)``.
A handle is not thread-safe: use it from one thread (or one event loop).
Commands are fire-and-forget; their outcome arrives as events from :meth:`Worker.poll`
(or the async iterator :meth:`Worker.events`). All events are frozen dataclasses from
:mod:`sessions.worker.messages` with ``to_dict()``.

Liveness: every :meth:`poll` checks that the worker process is alive and that its heartbeat (in
the ring's header, written every cycle and every idle poll) is younger than
``options.heartbeat_timeout`` (100 ms). If not, the handle reports the running session
``aborted`` (a :class:`SessionEnded` built from the telemetry it has followed), then
:class:`WorkerLost`, and kills a hung worker so that it cannot come back to drive the motor
(on an ODrive, the device watchdog then zeroes the torque by itself). Call :meth:`poll` at a
steady pace (10-50 Hz is plenty) while a session runs.

A worker is lost however it goes: killed, crashed (the process gone without a word), exited
when nobody asked it to (an unhandled bug, SIGTERM from elsewhere: its ``exited`` event names
why), hung, or found gone when a command cannot be sent (a broken pipe). Only
:meth:`shutdown` ends a worker without losing it. A lost handle refuses every command with
a :class:`WorkerError` that says so; the owner replaces it with a new :class:`Worker`.

Usage::

    with Worker(MachineSpec(kind="sim")) as worker:
        worker.start()
        worker.start_session(cfg, "s-1")
        reader = worker.open_reader()
        while worker.status().state in ("running", "stopping"):
            for ev in worker.poll(): ...
            batch = reader.read()          # full-rate records, batch.missed lost ones
"""

from __future__ import annotations

import asyncio
import contextlib
import multiprocessing as mp
import os
import signal
import time
from collections.abc import AsyncIterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sessions.codes import DONE, WorkerStateName
from sessions.config import SessionConfig, parse_session_config
from sessions.machine.spec import MachineSpec, check_controller
from sessions.summary import SessionSummary
from sessions.worker.channel import EventReceiver
from sessions.worker.messages import (
    CandidateMeasured,
    EStopped,
    Event,
    Faulted,
    RealtimeInfo,
    Rejected,
    Reset,
    ResetDone,
    SessionEnded,
    SessionStarted,
    Shutdown,
    StartSession,
    Stop,
    Stopping,
    Timing,
    TimingStats,
    WorkerExited,
    WorkerLost,
    WorkerReady,
)
from sessions.worker.options import WorkerOptions
from sessions.worker.process import worker_main
from sessions.worker.ring import (
    H_CYCLES,
    H_HEAD,
    H_HEARTBEAT,
    INDEX,
    RingInfo,
    RingReader,
    TelemetryRing,
    stamp_estop,
)

EXIT_GRACE = 2.0  # s a worker that announced its exit may take to be gone before it is killed


class WorkerError(RuntimeError):
    """The worker cannot do what was asked (not started, busy, latched, gone)."""


@dataclass(frozen=True)
class WorkerStatus:
    """A snapshot of the worker as the handle knows it (after draining its events)."""

    state: WorkerStateName
    pid: int | None
    machine: str
    session_id: str | None  # the running (or stopping) session
    fault: str | None  # the latched fault, or why the worker was lost
    heartbeat_age: float | None  # s since the worker's last heartbeat
    cycles: int  # cycles of the current/last session
    ring_head: int  # records written to the ring so far
    timing: TimingStats | None  # latest loop timing of the current/last session
    realtime: RealtimeInfo | None
    last_end: SessionEnded | None  # how the last session ended


@dataclass
class _Follow:
    """The parent's own account of a running session, from the ring: enough to summarise it
    if the worker dies."""

    session_id: str
    cfg: SessionConfig
    reader: RingReader
    k: int = 0
    t_last: float = 0.0
    w_last: float = 0.0
    w_min: float = 0.0
    power_sum: float = 0.0
    peak: float = 0.0
    gamma: float = 0.0
    phase: float = 0.0
    last_seq: int = -1
    evaluations: list[CandidateMeasured] = field(default_factory=list)

    def update(self) -> None:
        while True:
            batch = self.reader.read(max_records=100_000)
            if not len(batch):
                return
            d = batch.data
            self.last_seq = int(batch.seq[-1])
            run = d[d[:, INDEX["phase"]] >= 0.0]
            if len(run):
                tau, w, wcol = run[:, INDEX["tau"]], run[:, INDEX["w"]], run[:, INDEX["W"]]
                pm = tau * w
                self.k += len(run)
                self.t_last = float(run[-1, INDEX["t"]])
                self.power_sum += float(pm.sum())
                self.peak = max(self.peak, float(pm.max()))
                self.w_min = min(self.w_min, float(wcol.min()))
                self.w_last = float(wcol[-1])
                self.gamma = float(run[-1, INDEX["gamma"]])
                self.phase = float(run[-1, INDEX["phase"]])

    def summary(self, reason: str) -> SessionSummary:
        evs = self.evaluations
        optimum_w = optimum_p = None
        if evs and self.gamma > 0:
            optimum_w = self.gamma
            nearest = min(evs, key=lambda e: (abs(e.candidate - self.gamma), -e.session_t))
            optimum_p = nearest.power if np.isfinite(nearest.power) else None
        return SessionSummary(
            optimum_w=optimum_w,
            optimum_p=optimum_p,
            converged=self.phase == DONE,
            seeker=self.cfg.seeker.kind,
            mean_power=self.power_sum / self.k if self.k else 0.0,
            peak_power=self.peak,
            work=self.w_last,
            duration=self.k * self.cfg.dt,
            passivity_min=min(0.0, self.w_min),
            evaluations=len(evs),
            abort_reason=reason,
        )


class Worker:
    """Spawn and drive one worker process (``spawn`` context) and its telemetry ring."""

    def __init__(
        self, machine: MachineSpec | None = None, options: WorkerOptions | None = None
    ) -> None:
        self.spec = machine or MachineSpec()
        self.options = options or WorkerOptions()
        self._ctx = mp.get_context("spawn")
        self._proc: Any = None
        self._ring: TelemetryRing | None = None
        self._cmd: Any = None
        self._events: EventReceiver | None = None
        self._state: WorkerStateName = "starting"
        self._ready: WorkerReady | None = None
        self._fault: str | None = None
        self._session: str | None = None
        self._starting: tuple[str, SessionConfig] | None = None
        self._follow: _Follow | None = None
        self._timing: TimingStats | None = None
        self._last_end: SessionEnded | None = None
        self._backlog: list[Event] = []
        self._closed = False
        self._stopping = False  # shutdown() asked the worker to exit
        self._exited: str | None = None  # the reason of a WorkerExited nobody asked for
        self._exit_seen: float | None = None  # when that exit was first noticed

    # -- life --------------------------------------------------------------------------------
    def start(self, timeout: float | None = None, *, wait: bool = True) -> WorkerReady | None:
        """Spawn the worker; with ``wait``, block until it reports ready (it has connected
        its machine; ``ready.fault`` says if that failed) and return that event."""
        if self._proc is not None:
            raise WorkerError("worker already started")
        self._ring = TelemetryRing.create(self.options.ring_capacity)
        cmd_r, cmd_w = self._ctx.Pipe(duplex=False)
        ev_r, ev_w = self._ctx.Pipe(duplex=False)
        self._proc = self._ctx.Process(
            target=worker_main,
            args=(cmd_r, ev_w, self._ring.name, self.spec, self.options, os.getpid()),
            name="ergoseek-worker",
            daemon=True,
        )
        self._proc.start()
        cmd_r.close()
        ev_w.close()
        self._cmd = cmd_w
        self._events = EventReceiver(ev_r)
        if not wait:
            return None
        limit = self.options.start_timeout if timeout is None else timeout
        deadline = time.monotonic() + limit
        while self._ready is None:
            self._backlog.extend(self.poll())
            if self._state in ("lost", "closed"):
                raise WorkerError(f"the worker failed to start: {self._fault}")
            if time.monotonic() > deadline:
                self._kill()
                raise WorkerError(f"the worker did not report ready within {limit:g} s")
            time.sleep(0.005)
        self._backlog = [ev for ev in self._backlog if not isinstance(ev, WorkerReady)]
        return self._ready

    def shutdown(self, timeout: float = 5.0) -> list[Event]:
        """Stop any session at once (zero torque), disarm, close the machine, end the process,
        remove the ring. Waits at most ``timeout`` (then kills). Returns the last events."""
        if self._closed:
            return []
        out, self._backlog = self._backlog, []
        self._stopping = True
        proc = self._proc
        if proc is not None and proc.is_alive():
            with contextlib.suppress(OSError, ValueError):
                self._cmd.send(Shutdown())
            deadline = time.monotonic() + timeout
            while proc.is_alive() and time.monotonic() < deadline:
                out.extend(self._drain())
                proc.join(0.01)
            if proc.is_alive():
                proc.terminate()
                proc.join(1.0)
            if proc.is_alive():
                self._kill()
        out.extend(self._drain())
        if self._state != "lost":
            self._state = "closed"
        self._closed = True
        for conn in (self._cmd,):
            if conn is not None:
                conn.close()
        if self._events is not None:
            self._events.close()
        if self._follow is not None:
            self._follow.reader.close()
            self._follow = None
        if self._ring is not None:
            self._ring.close()
            self._ring = None
        return out

    close = shutdown

    def __enter__(self) -> Worker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()

    # -- commands (non-blocking) ------------------------------------------------------------
    def start_session(self, cfg: SessionConfig | Mapping[str, Any], session_id: str) -> None:
        """Ask for a session. Raises ScenarioError for an invalid config, ValueError if this
        machine cannot run it, WorkerError if the worker is not idle. The outcome arrives as
        :class:`SessionStarted` or :class:`Rejected`."""
        if not isinstance(cfg, SessionConfig):
            cfg = parse_session_config(dict(cfg))
        if not isinstance(session_id, str) or not session_id:
            raise ValueError("session_id must be a non-empty string")
        check_controller(self.spec.kind, self.spec.has_torque_sensor, cfg.controller.kind)
        self._poll_into_backlog()
        if self._state != "idle":
            why = f": {self._fault}" if self._fault else ""
            raise WorkerError(f"the worker is {self._state}{why}")
        if self._starting is not None or self._session is not None:
            raise WorkerError("a session is already starting or running")
        self._starting = (session_id, cfg)
        self._send(StartSession(cfg, session_id))

    def stop(self, immediate: bool = False, reason: str | None = None) -> None:
        """End the running session: torque ramped out (or zero at once with ``immediate``);
        ``reason`` is the session's (default: the operator's stop)."""
        self._send(Stop(immediate, reason))

    def estop(self) -> float:
        """Emergency stop: the worker writes zero torque on its next cycle and latches until
        :meth:`reset`. Through the e-stop line of the ring's header (the worker looks at it
        every period, before its command pipe), so nothing queued can delay it. Returns the
        monotonic time it was asked; a lost worker raises WorkerError (the line is pulled
        all the same)."""
        if self._ring is None or self._closed:
            raise WorkerError("the worker is not running")
        t = time.monotonic()
        stamp_estop(self._ring.view.hdr)  # pulled even if it looks gone: it costs nothing
        if self._state == "lost":  # nothing drives the motor; the caller is told so
            raise WorkerError(f"the worker is lost ({self._fault}): reset it")
        return t

    def reset(self) -> None:
        """Clear a latched e-stop or fault (never restarts motion)."""
        self._send(Reset(time.monotonic_ns()))

    def _send(self, cmd: object) -> None:
        if self._cmd is None or self._closed:
            raise WorkerError("the worker is not running")
        if self._state in ("lost", "closed") and not self._stopping:
            self._backlog.extend(self._drain())
            self._backlog.extend(self._check_alive())
            if self._state == "lost":
                raise WorkerError(f"the worker is lost ({self._fault}): reset it")
            raise WorkerError(f"the worker has exited ({self._exited}): reset it")
        try:
            self._cmd.send(cmd)
        except (OSError, ValueError) as exc:
            # the worker's end of the pipe is gone: so is the worker (or it is broken)
            self._backlog.extend(self._drain())
            self._backlog.extend(self._check_alive())
            if self._state != "lost":
                self._kill()
                self._backlog.extend(self._lost(f"worker unreachable ({exc})", None))
            raise WorkerError(f"the worker is lost ({self._fault}): reset it") from None

    # -- observation (non-blocking) -----------------------------------------------------------
    def poll(self) -> list[Event]:
        """New events, in order, and the liveness check. Never blocks."""
        out, self._backlog = self._backlog, []
        out.extend(self._drain())
        if self._follow is not None:
            self._follow.update()
        out.extend(self._check_alive())
        return out

    def _poll_into_backlog(self) -> None:
        self._backlog.extend(self._drain())

    async def events(self, interval: float = 0.02) -> AsyncIterator[Event]:
        """Events as they come, polling every ``interval`` s; ends when the worker is gone."""
        while True:
            for ev in self.poll():
                yield ev
            if self._state in ("closed", "lost"):
                return
            await asyncio.sleep(interval)

    def status(self) -> WorkerStatus:
        self._poll_into_backlog()
        ring = self._ring
        age = None
        head = cycles = 0
        if ring is not None:
            hb = ring.header(H_HEARTBEAT)
            age = (time.monotonic_ns() - hb) * 1e-9 if hb else None
            head = ring.header(H_HEAD)
            cycles = ring.header(H_CYCLES)
        return WorkerStatus(
            state=self._state,
            pid=self.pid,
            machine=self.spec.kind,
            session_id=self._session,
            fault=self._fault,
            heartbeat_age=age,
            cycles=cycles,
            ring_head=head,
            timing=self._timing,
            realtime=self._ready.realtime if self._ready else None,
            last_end=self._last_end,
        )

    def open_reader(self, start: str | int = "now") -> RingReader:
        """A reader of the full-rate telemetry (see :class:`RingReader`); close it when done."""
        if self._ring is None:
            raise WorkerError("the worker is not running")
        return RingReader(self._ring.info, start)

    @property
    def ring_info(self) -> RingInfo:
        """Name and size of the ring: enough for a reader in another process."""
        if self._ring is None:
            raise WorkerError("the worker is not running")
        return self._ring.info

    @property
    def pid(self) -> int | None:
        return self._proc.pid if self._proc is not None else None

    @property
    def state(self) -> WorkerStateName:
        return self._state

    # -- internals ------------------------------------------------------------------------------
    def _drain(self) -> list[Event]:
        if self._events is None:
            return []
        evs = self._events.receive()
        for ev in evs:
            self._apply(ev)
        return evs

    def _apply(self, ev: Event) -> None:
        if isinstance(ev, WorkerReady):
            self._ready = ev
            self._fault = ev.fault
            self._state = "faulted" if ev.fault else "idle"
        elif isinstance(ev, SessionStarted):
            cfg = self._starting[1] if self._starting else None
            self._starting = None
            self._session = ev.session_id
            self._state = "running"
            self._timing = None
            if cfg is not None and self._ring is not None:
                reader = RingReader(self._ring.info, ev.first_seq)
                self._follow = _Follow(ev.session_id, cfg, reader)
        elif isinstance(ev, Rejected):
            if ev.command == "start":
                self._starting = None
        elif isinstance(ev, CandidateMeasured):
            if self._follow is not None:
                self._follow.evaluations.append(ev)
        elif isinstance(ev, Stopping):
            self._state = "stopping"
        elif isinstance(ev, Timing):
            self._timing = ev.stats
        elif isinstance(ev, EStopped):
            self._state = "estopped"
        elif isinstance(ev, Faulted):
            self._state = "faulted"
            self._fault = ev.reason
            self._starting = None
        elif isinstance(ev, SessionEnded):
            self._session = None
            self._last_end = ev
            self._timing = ev.timing
            self._state = ev.state_after
            if ev.state_after != "faulted":
                self._fault = None
            if self._follow is not None:
                self._follow.reader.close()
                self._follow = None
        elif isinstance(ev, ResetDone):
            self._fault = ev.fault
            self._state = "faulted" if ev.fault else "idle"
        elif isinstance(ev, WorkerExited):
            self._state = "closed"
            if not self._stopping:
                self._exited = ev.reason

    def _check_alive(self) -> list[Event]:
        proc = self._proc
        if proc is None or self._state == "lost" or self._closed:
            return []
        if self._exited is not None:  # it said goodbye, but nobody had asked it to go
            return self._exiting(proc)
        if self._state == "closed":
            return []
        if not proc.is_alive():
            late = self._drain()  # what it managed to send before it died
            if self._exited is not None:
                return late + self._exiting(proc)
            if self._state == "closed":
                return late
            return late + self._lost(f"worker died (exit code {proc.exitcode})", proc.exitcode)
        if self._ready is None or self._ring is None:
            return []  # still starting: start() bounds that wait
        hb = self._ring.header(H_HEARTBEAT)
        age = (time.monotonic_ns() - hb) * 1e-9
        if age > self.options.heartbeat_timeout:
            late = self._drain()  # a goodbye sent since the last drain is not a hang
            if self._exited is not None:
                return late + self._exiting(proc)
            self._kill()
            why = f"worker unresponsive: no heartbeat for {age * 1e3:.0f} ms"
            return late + self._lost(why, None)
        return []

    def _exiting(self, proc: Any) -> list[Event]:
        """A worker that announced its exit unasked: lost once the process is gone (killed if
        it lingers past :data:`EXIT_GRACE`)."""
        if proc.is_alive():
            now = time.monotonic()
            if self._exit_seen is None:
                self._exit_seen = now
            if now - self._exit_seen < EXIT_GRACE:
                return []
            self._kill()
        return self._lost(f"worker exited: {self._exited}", proc.exitcode)

    def _lost(self, reason: str, exitcode: int | None) -> list[Event]:
        out: list[Event] = []
        now = time.monotonic()
        follow = self._follow
        if follow is not None:
            follow.update()
            out.append(
                SessionEnded(
                    now,
                    follow.session_id,
                    "aborted",
                    reason,
                    follow.summary(reason),
                    follow.last_seq,
                    self._timing or TimingStats(),
                    "lost",
                )
            )
            follow.reader.close()
            self._follow = None
            self._last_end = out[0]  # type: ignore[assignment]
        self._session = None
        self._starting = None
        self._state = "lost"
        self._fault = reason
        out.append(WorkerLost(now, reason, exitcode))
        return out

    def _kill(self) -> None:
        proc = self._proc
        if proc is not None and proc.is_alive() and proc.pid:
            with contextlib.suppress(ProcessLookupError):
                os.kill(proc.pid, signal.SIGKILL)
            proc.join(1.0)
