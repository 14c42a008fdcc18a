"""The worker process: runs live sessions, one at a time, in real time.

Started by :class:`sessions.worker.handle.Worker` (spawn context). It owns the machine; the
parent never touches it. Between sessions it waits for commands (polling every
``idle_poll``, beating its heartbeat); during a session it runs the hot loop:

    wait for the deadline (sleep, then spin)  →  commands  →  read  →  Loop.step  →  safety
    →  write  →  ring record + heartbeat  →  timing

Safety, in the order it acts:
- **e-stop** (command): zero torque written the same cycle the command is seen, drive
  disarmed, latched (state ``estopped``) until a reset; a reset never starts anything. The
  session ends ``stopped`` (reason ``e-stop``): an operator's decision, like a stop.
- **machine fault** (timeout, garbage, drive error): the backend has already written zero
  torque; the session ends ``faulted``; latched until a reset.
- **parent gone** (the command pipe closes or the parent pid changes), **SIGTERM**: zero torque
  at once, disarm, exit.
- **velocity over the limit** and **passivity breach** (W < −c²): a controlled stop
  (:class:`sessions.worker.safety.StopRamp`), the session ends ``aborted``.
- **duration reached**: a controlled stop, ``completed``. **Stop** (command): controlled,
  ``stopped`` (or at once with ``immediate``).
- The torque clamp is the engine's (:mod:`sessions.limits`) and the machine's own.

The garbage collector is frozen and disabled for the hot loop (the loop allocates only
short-lived floats and tuples, freed by reference counting). CPU pinning, SCHED_FIFO and a 1 µs
timer slack are asked for when configured, and refused quietly (:class:`RealtimeInfo`).
"""

from __future__ import annotations

import gc
import math
import os
import select
import signal
import sys
import time
import traceback
from dataclasses import dataclass
from multiprocessing.connection import Connection

from sessions.config import SessionConfig
from sessions.limits import TORQUE_LIMIT, VELOCITY_LIMIT
from sessions.loop import Loop
from sessions.machine import Machine, MachineError, MachineSpec, MachineState, make_machine
from sessions.summary import SessionSummary, summarize
from sessions.worker.channel import EventSender
from sessions.worker.messages import (
    STATES,
    EndStatus,
    EStop,
    EStopped,
    Faulted,
    LimitHit,
    Rejected,
    Reset,
    ResetDone,
    SeekerEvaluation,
    SessionEnded,
    SessionStarted,
    Shutdown,
    StartSession,
    Stop,
    Stopping,
    Timing,
    WorkerExited,
    WorkerReady,
)
from sessions.worker.ring import (
    FLAG_ESTOP,
    FLAG_FAULT,
    FLAG_PASSIVITY,
    FLAG_STOPPING,
    H_CYCLES,
    H_HEARTBEAT,
    H_PID,
    H_SESSION,
    H_STATE,
    STATE_CLOSED,
    STATE_ESTOPPED,
    STATE_FAULTED,
    STATE_IDLE,
    STATE_RUNNING,
    STATE_STARTING,
    STATE_STOPPING,
    RingWriter,
)
from sessions.worker.safety import StopRamp
from sessions.worker.timing import TimingRecorder, setup_realtime


@dataclass(frozen=True)
class WorkerOptions:
    """How the worker runs (the session's loop rate comes from its config)."""

    ring_capacity: int = 1 << 15  # records (32 s at 1 kHz)
    spin_us: float = 200.0  # spin on the clock for the last stretch before each deadline
    cpu: int | None = None  # pin the worker to this CPU
    realtime: bool = True  # ask for SCHED_FIFO (quietly refused if not permitted)
    priority: int = 50  # SCHED_FIFO priority
    timer_slack_ns: int | None = 1000  # prctl(PR_SET_TIMERSLACK): sharper sleeps
    stop_ramp: float = 0.5  # s, torque ramp of a controlled stop
    heartbeat_timeout: float = 0.1  # s without a heartbeat: the parent declares the worker lost
    timing_interval: float = 1.0  # s between Timing events
    idle_poll: float = 0.002  # s between heartbeats when no session runs
    start_timeout: float = 60.0  # s for the worker to import, connect and report ready


@dataclass(frozen=True)
class _End:
    """How a session ended, and the state the worker latches afterwards (None: idle)."""

    status: EndStatus
    reason: str
    latch: int | None = None


def worker_main(
    cmd_conn: Connection,
    event_conn: Connection,
    ring_name: str,
    spec: MachineSpec,
    options: WorkerOptions,
    parent_pid: int,
) -> None:
    """Entry point of the worker process."""
    WorkerProcess(cmd_conn, event_conn, ring_name, spec, options, parent_pid).run()


class WorkerProcess:
    def __init__(
        self,
        cmd_conn: Connection,
        event_conn: Connection,
        ring_name: str,
        spec: MachineSpec,
        options: WorkerOptions,
        parent_pid: int,
    ) -> None:
        self.cmds = cmd_conn
        self.cmd_poll = select.poll()
        self.cmd_poll.register(cmd_conn.fileno(), select.POLLIN)
        self.events = EventSender(event_conn)
        self.ring = RingWriter(ring_name)
        self.spec = spec
        self.opt = options
        self.parent_pid = parent_pid
        self.state = STATE_STARTING
        self.session_no = 0
        self.fault: str | None = None
        self.terminated = False
        self.shutdown = False
        self.exit_reason = ""
        self.stop_end: _End | None = None
        self.machine: Machine = make_machine(spec)
        self.machine.keepalive = self.beat

    # -- plumbing ------------------------------------------------------------------------
    def beat(self) -> None:
        self.ring.beat(self.state)

    def emit(self, ev: object) -> None:
        self.events.send(ev)

    def parent_alive(self) -> bool:
        return os.getppid() == self.parent_pid

    def _on_sigterm(self, signum: int, frame: object) -> None:
        self.terminated = True

    # -- life --------------------------------------------------------------------------------
    def run(self) -> None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
        signal.signal(signal.SIGTERM, self._on_sigterm)
        opt = self.opt
        rt = setup_realtime(opt.cpu, opt.realtime, opt.priority, opt.timer_slack_ns)
        self.ring.set(H_PID, os.getpid())
        try:
            self.machine.connect()
            self.state = STATE_IDLE
        except MachineError as exc:
            self.fault = str(exc)
            self.state = STATE_FAULTED
        self.beat()
        self.emit(WorkerReady(time.monotonic(), os.getpid(), self.spec.kind, rt, self.fault))
        try:
            self.idle_loop()
        except BaseException as exc:  # never leave without zeroing the torque
            self.exit_reason = f"internal error: {type(exc).__name__}: {exc}"
            traceback.print_exc(file=sys.stderr)
        finally:
            self.machine.zero()
            self.machine.close()
            self.state = STATE_CLOSED
            self.beat()
            self.emit(WorkerExited(time.monotonic(), self.exit_reason or "shutdown"))
            deadline = time.monotonic() + 0.5
            while self.events.pending and time.monotonic() < deadline and self.parent_alive():
                self.events.flush()
                time.sleep(0.001)
            self.ring.close()

    def idle_loop(self) -> None:
        while True:
            self.beat()
            if self.events.pending:
                self.events.flush()
            if self.terminated:
                self.exit_reason = "terminated (SIGTERM)"
                return
            if not self.parent_alive():
                self.exit_reason = "parent died"
                return
            try:
                if not self.cmd_poll.poll(self.opt.idle_poll * 1e3):
                    continue
                cmd = self.cmds.recv()
            except (EOFError, OSError):
                self.exit_reason = "parent died (command pipe closed)"
                return
            if isinstance(cmd, Shutdown):
                self.exit_reason = "shutdown"
                return
            self.idle_command(cmd)
            if self.shutdown or self.terminated:
                self.exit_reason = self.exit_reason or "shutdown"
                return

    def idle_command(self, cmd: object) -> None:
        now = time.monotonic()
        state = STATES[self.state]
        if isinstance(cmd, StartSession):
            if self.state != STATE_IDLE:
                why = f"the worker is {state}" + (f": {self.fault}" if self.fault else "")
                self.emit(Rejected(now, "start", why + "; reset first"))
                return
            self.run_session(cmd.cfg, cmd.session_id)
        elif isinstance(cmd, Stop):
            self.emit(Rejected(now, "stop", "no session is running"))
        elif isinstance(cmd, EStop):
            self.machine.zero()
            zero_at = time.monotonic()
            self._disarm()
            self.state = STATE_ESTOPPED
            self.beat()
            self.emit(EStopped(zero_at, None, zero_at))
        elif isinstance(cmd, Reset):
            self.reset()
        else:
            self.emit(Rejected(now, type(cmd).__name__, "unknown command"))

    def reset(self) -> None:
        if self.state == STATE_FAULTED:
            try:
                if self.machine.state is MachineState.UNCONNECTED:
                    self.machine.connect()
                else:
                    self.machine.reset()
            except MachineError as exc:
                self.fault = str(exc)
                self.emit(ResetDone(time.monotonic(), self.fault))
                return
        self.fault = None
        self.state = STATE_IDLE
        self.beat()
        self.emit(ResetDone(time.monotonic(), None))

    def _disarm(self) -> None:
        try:
            self.machine.disarm()
        except MachineError as exc:
            self.fault = str(exc)

    # -- a session ---------------------------------------------------------------------------
    def run_session(self, cfg: SessionConfig, session_id: str) -> None:
        machine = self.machine
        now = time.monotonic()
        try:
            loop = Loop(cfg)
        except Exception as exc:
            self.emit(Rejected(now, "start", f"cannot build the loop: {exc}"))
            return
        timing = TimingRecorder(cfg.rate)
        summary: list[SessionSummary] = []
        # collect before arming: from arming on, the drive's watchdog counts
        gc.collect()
        gc.freeze()
        gc.disable()
        try:
            try:
                machine.arm(cfg)
                q0, w0, _ = machine.read()
            except ValueError as exc:
                self.emit(Rejected(now, "start", str(exc)))
                return
            except MachineError as exc:
                self.fault = str(exc)
                self.state = STATE_FAULTED
                self.beat()
                self.emit(Faulted(time.monotonic(), session_id, self.fault))
                self.emit(Rejected(now, "start", f"machine fault: {self.fault}"))
                return
            loop.begin(q0, w0)
            machine.activate()
            self.session_no += 1
            self.ring.set(H_SESSION, self.session_no)
            first_seq = self.ring.head
            self.state = STATE_RUNNING
            self.beat()
            self.emit(
                SessionStarted(
                    time.monotonic(),
                    session_id,
                    self.session_no,
                    first_seq,
                    cfg.rate,
                    cfg.duration,
                )
            )
            try:
                end = self.hot_loop(loop, cfg, session_id, timing, summary)
            except Exception as exc:  # a bug must still leave the machine safe
                machine.zero()
                traceback.print_exc(file=sys.stderr)
                end = _End("faulted", f"internal error: {type(exc).__name__}: {exc}", STATE_FAULTED)
                self.emit(Faulted(time.monotonic(), session_id, end.reason))
        finally:
            gc.unfreeze()
            gc.enable()
        if not summary:
            summary.append(summarize(loop, end.reason if end.status != "completed" else None))
        if machine.state in (MachineState.ACTIVE, MachineState.ARMED):
            self._disarm()
        if end.latch == STATE_FAULTED:
            self.fault = end.reason
        self.state = end.latch if end.latch is not None else STATE_IDLE
        if self.fault and self.state == STATE_IDLE:
            self.state = STATE_FAULTED  # disarming failed
        self.beat()
        self.emit(
            SessionEnded(
                time.monotonic(),
                session_id,
                end.status,
                end.reason,
                summary[0],
                self.ring.head - 1 if self.ring.head > first_seq else -1,
                timing.stats(),
                STATES[self.state],
            )
        )

    def hot_loop(
        self,
        loop: Loop,
        cfg: SessionConfig,
        sid: str,
        timing: TimingRecorder,
        summary: list[SessionSummary],
    ) -> _End:
        """Cycles until the session ends; returns how. ``summary`` receives the session's
        summary when its result is frozen (at the start of a stop)."""
        opt = self.opt
        machine = self.machine
        read, write = machine.read, machine.write
        step = loop.step
        ring = self.ring
        rwrite = ring.write
        hdr = ring.hdr
        emit = self.emit
        events = self.events
        recv = self.cmds.recv
        cmd_poll = self.cmd_poll.poll
        mono = time.monotonic
        mono_ns = time.monotonic_ns
        sleep = time.sleep
        seeker = loop.seeker
        passivity = loop.passivity
        limits = loop.limits
        rate = cfg.rate
        dt = loop.dt
        period = 1.0 / rate
        spin = opt.spin_us * 1e-6
        n_steps = round(cfg.duration * rate)
        session = float(self.session_no)
        nan = math.nan
        ramp: StopRamp | None = None
        end: _End | None = None
        prev_flags = 0
        interval = opt.timing_interval
        next_timing = mono() + interval
        cycles = 0
        row = loop.row
        q = w = 0.0
        deadline = mono() + period
        while True:
            # -- wait for the deadline: sleep, then spin
            now = mono()
            rem = deadline - now
            if rem > spin:
                sleep(rem - spin)
                now = mono()
            while now < deadline:
                now = mono()
            late = now - deadline
            if late >= period:
                skipped = int(late / period)
                timing.missed += skipped
                deadline += skipped * period
            deadline += period
            cycles += 1

            # -- commands and supervision
            flags = 0
            if cmd_poll(0):
                try:
                    cmd = recv()
                except (EOFError, OSError):
                    cmd = None
                    self.terminated = True
                    self.exit_reason = "parent died (command pipe closed)"
                if isinstance(cmd, EStop):
                    machine.zero()
                    zero_at = mono()
                    emit(EStopped(zero_at, sid, zero_at))
                    end = _End("stopped", "e-stop", STATE_ESTOPPED)
                    flags = FLAG_ESTOP
                elif isinstance(cmd, Stop):
                    if cmd.immediate or ramp is not None:
                        machine.zero()
                        end = _End("stopped", "stopped at once by the operator")
                    else:
                        ramp = self._begin_stop(
                            loop, sid, "stopped", "stopped by the operator", summary, ramp
                        )
                elif isinstance(cmd, Shutdown):
                    machine.zero()
                    self.shutdown = True
                    self.exit_reason = "shutdown"
                    end = _End("stopped", "worker shut down")
                elif isinstance(cmd, StartSession):
                    emit(Rejected(now, "start", "a session is running"))
                elif isinstance(cmd, Reset):
                    emit(Rejected(now, "reset", "a session is running; stop it first"))
            if (cycles & 7) == 0 and os.getppid() != self.parent_pid:
                self.terminated = True
                self.exit_reason = "parent died"
            if self.terminated and end is None:
                machine.zero()
                self.exit_reason = self.exit_reason or "terminated (SIGTERM)"
                end = _End("aborted", self.exit_reason)
            if end is not None:
                if not summary:
                    summary.append(summarize(loop, end.reason))
                # the cycle that wrote zero torque: one period after the last record
                rwrite(
                    (row[0] + dt, *row[1:5], 0.0, *row[6:], 0.0, -1.0, float(flags), late * 1e6,
                     now, session)
                )  # fmt: skip
                return end

            # -- read, update, write
            try:
                q, w, tau = read()
                if ramp is None:
                    u = step(q, w, tau)
                    row = loop.row
                    phase = float(seeker.phase)
                    lf = loop.flags
                    flags = lf
                    ev = loop.evaluation
                    if ev is not None:
                        emit(
                            SeekerEvaluation(
                                now,
                                sid,
                                ev.t,
                                ev.candidate,
                                ev.power,
                                ev.stderr,
                                seeker.target,
                                seeker.done,
                                seeker.bracket[0],
                                seeker.bracket[1],
                                seeker.fraction(),
                            )
                        )
                    if lf != prev_flags:
                        if lf & TORQUE_LIMIT and not prev_flags & TORQUE_LIMIT:
                            emit(LimitHit(now, sid, row[0], "torque", abs(u)))
                        if lf & VELOCITY_LIMIT and not prev_flags & VELOCITY_LIMIT:
                            emit(LimitHit(now, sid, row[0], "velocity", abs(w)))
                        prev_flags = lf
                    if lf & VELOCITY_LIMIT:
                        ramp = self._begin_stop(
                            loop,
                            sid,
                            "aborted",
                            f"velocity over the limit: |w| = {abs(w):.2f} > "
                            f"{limits.max_velocity:g} rad/s",
                            summary,
                            ramp,
                            u,
                        )
                    elif passivity.breached:
                        flags |= FLAG_PASSIVITY
                        emit(LimitHit(now, sid, row[0], "passivity", passivity.work))
                        ramp = self._begin_stop(
                            loop,
                            sid,
                            "aborted",
                            f"passivity breached: W = {passivity.work:.3g} J < "
                            f"-c² = {-passivity.c2:g} J",
                            summary,
                            ramp,
                            u,
                        )
                    elif loop.k >= n_steps:
                        ramp = self._begin_stop(
                            loop, sid, "completed", "duration reached", summary, ramp, u
                        )
                else:
                    u = ramp.command(w)
                    t = (loop.k + ramp.k - 1) * dt
                    row = (t, q, w, nan, nan, u, nan, nan, passivity.work, seeker.target)
                    phase = -1.0
                    flags = FLAG_STOPPING | limits.flags
                write(u)
            except MachineError as exc:
                reason = str(exc)
                emit(Faulted(mono(), sid, reason))
                if not summary:
                    summary.append(summarize(loop, reason))
                rwrite(
                    (
                        row[0] + dt,
                        *row[1:5],
                        0.0,
                        *row[6:],
                        0.0,
                        -1.0,
                        float(FLAG_FAULT),
                        late * 1e6,
                        now,
                        session,
                    )
                )
                return _End("faulted", reason, STATE_FAULTED)

            # -- publish
            rwrite((*row, u, phase, float(flags), late * 1e6, now, session))
            hdr[H_HEARTBEAT] = mono_ns()
            hdr[H_CYCLES] = cycles
            timing.record(late, mono() - now)
            if ramp is not None and ramp.done:
                assert self.stop_end is not None
                return self.stop_end
            if now >= next_timing:
                next_timing += interval
                emit(Timing(now, sid, timing.stats()))
            if events.pending:
                events.flush()

    def _begin_stop(
        self,
        loop: Loop,
        sid: str,
        status: EndStatus,
        reason: str,
        summary: list[SessionSummary],
        ramp: StopRamp | None,
        u0: float | None = None,
    ) -> StopRamp:
        """Freeze the session's result and start the controlled stop (once)."""
        if ramp is not None:
            return ramp
        if not summary:
            summary.append(summarize(loop, None if status == "completed" else reason))
        self.stop_end = _End(status, reason)
        self.state = STATE_STOPPING
        self.ring.hdr[H_STATE] = STATE_STOPPING
        self.emit(Stopping(time.monotonic(), sid, reason))
        u = self.machine.last_command if u0 is None else u0
        return StopRamp(u, self.opt.stop_ramp, loop.dt, loop.limits)
