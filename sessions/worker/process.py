"""The worker process: runs live sessions, one at a time, in real time.

Started by :class:`sessions.worker.handle.Worker` (spawn context). It owns the machine; the
parent never touches it. Its life (this module): connect the machine, then between sessions
wait for commands (polling every ``idle_poll``, beating its heartbeat); for each session, arm
the machine, run the session's cycles (:class:`sessions.worker.cycle.SessionCycle`: read →
step → supervise → write → publish, its safety decisions in :mod:`sessions.worker.supervisor`),
disarm, and report how it ended. Whatever happens, it leaves with zero torque written.

Between sessions: an **e-stop** writes zero torque, disarms and latches (state ``estopped``)
until a reset; a reset never starts anything. **Parent gone**, **SIGTERM**, **shutdown**: zero
torque, disarm, exit.

The garbage collector is frozen and disabled while a session runs (the loop allocates only
short-lived floats and tuples, freed by reference counting). CPU pinning, SCHED_FIFO and a 1 µs
timer slack are asked for when configured, and refused quietly (:class:`RealtimeInfo`).
"""

from __future__ import annotations

import gc
import os
import select
import signal
import sys
import time
import traceback
from multiprocessing.connection import Connection

from sessions.codes import (
    STATE_CLOSED,
    STATE_ESTOPPED,
    STATE_FAULTED,
    STATE_IDLE,
    STATE_RUNNING,
    STATE_STARTING,
    STATE_STOPPING,
    STATES,
)
from sessions.config import SessionConfig
from sessions.loop import Loop
from sessions.machine import Machine, MachineError, MachineSpec, MachineState, make_machine
from sessions.worker.channel import EventSender
from sessions.worker.cycle import SessionCycle
from sessions.worker.messages import (
    EStop,
    EStopped,
    Faulted,
    Rejected,
    Reset,
    ResetDone,
    SessionEnded,
    SessionStarted,
    Shutdown,
    StartSession,
    Stop,
    WorkerExited,
    WorkerReady,
)
from sessions.worker.options import WorkerOptions
from sessions.worker.pacer import setup_realtime
from sessions.worker.ring import H_ESTOP, H_PID, H_SESSION, H_STATE, RingWriter
from sessions.worker.supervisor import End


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
        self.estop_seen = int(self.ring.hdr[H_ESTOP])  # the e-stop line's last stamp acted on
        self.exit_reason = ""
        self.machine: Machine = make_machine(spec)
        self.machine.keepalive = self.beat

    # -- plumbing ------------------------------------------------------------------------
    def beat(self) -> None:
        self.ring.beat(self.state)

    def estop_requested(self) -> bool:
        """A new stamp on the e-stop line (:class:`sessions.worker.ring.EStopLine`)."""
        stamp = int(self.ring.hdr[H_ESTOP])
        if stamp == self.estop_seen:
            return False
        self.estop_seen = stamp
        return True

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
        failure: BaseException | None = None
        try:
            self.idle_loop()
        except BaseException as exc:  # never leave without zeroing the torque
            failure = exc
            self.exit_reason = f"internal error: {type(exc).__name__}: {exc}"
        finally:
            self.machine.zero()
            self.beat()  # alive, and going: the heartbeat's timeout spans only the close
            self.machine.close()
            self.state = STATE_CLOSED
            self.beat()
            self.emit(WorkerExited(time.monotonic(), self.exit_reason or "shutdown"))
            deadline = time.monotonic() + 0.5
            while self.events.pending and time.monotonic() < deadline and self.parent_alive():
                self.events.flush()
                time.sleep(0.001)
            if failure is not None:  # after the goodbye: formatting a traceback takes ms
                traceback.print_exception(failure, file=sys.stderr)
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
            if self.estop_requested():  # before any command: a reset sent after it follows it
                self.idle_command(EStop())
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
            if self.state == STATE_ESTOPPED and cmd.sent_ns < self.estop_seen:
                self.emit(Rejected(now, "reset", "asked before the e-stop it would clear"))
                return
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
    def enter_stopping(self) -> None:
        """A controlled stop has begun (the supervisor's decision)."""
        self.state = STATE_STOPPING
        self.ring.hdr[H_STATE] = STATE_STOPPING

    def run_session(self, cfg: SessionConfig, session_id: str) -> None:
        now = time.monotonic()
        try:
            loop = Loop(cfg)
        except Exception as exc:
            self.emit(Rejected(now, "start", f"cannot build the loop: {exc}"))
            return
        # collect before arming: from arming on, the drive's watchdog counts
        gc.collect()
        gc.freeze()
        gc.disable()
        try:
            if not self._arm(loop, cfg, session_id, now):
                return
            first_seq = self._started(cfg, session_id)
            cycle = SessionCycle(self, loop, cfg, session_id)
            end = self._cycles(cycle)
        finally:
            gc.unfreeze()
            gc.enable()
        self._ended(cycle, end, first_seq)

    def _arm(self, loop: Loop, cfg: SessionConfig, sid: str, now: float) -> bool:
        """Arm the machine and start the loop at its state; a refusal or fault is reported."""
        machine = self.machine
        try:
            machine.follow(loop.reference)  # the protocol's cues (a simulated person follows)
            machine.arm(cfg)
            q0, w0, _ = machine.read()
        except ValueError as exc:
            self.emit(Rejected(now, "start", str(exc)))
            return False
        except MachineError as exc:
            self.fault = str(exc)
            self.state = STATE_FAULTED
            self.beat()
            self.emit(Faulted(time.monotonic(), sid, self.fault))
            self.emit(Rejected(now, "start", f"machine fault: {self.fault}"))
            return False
        truth = machine.truth()
        if truth is not None:  # a simulated person: the summary scores the regret
            loop.attach_truth(truth)
        loop.begin(q0, w0)
        machine.activate()
        return True

    def _started(self, cfg: SessionConfig, sid: str) -> int:
        """The session is running: numbered, announced; returns its first ring record."""
        self.session_no += 1
        self.ring.set(H_SESSION, self.session_no)
        first_seq = self.ring.head
        self.state = STATE_RUNNING
        self.beat()
        self.emit(
            SessionStarted(
                time.monotonic(), sid, self.session_no, first_seq, cfg.rate, cfg.duration
            )
        )
        return first_seq

    def _cycles(self, cycle: SessionCycle) -> End:
        try:
            return cycle.run()
        except Exception as exc:  # a bug must still leave the machine safe
            self.machine.zero()
            traceback.print_exc(file=sys.stderr)
            end = End("faulted", f"internal error: {type(exc).__name__}: {exc}", STATE_FAULTED)
            self.emit(Faulted(time.monotonic(), cycle.sid, end.reason))
            return end

    def _ended(self, cycle: SessionCycle, end: End, first_seq: int) -> None:
        """Disarm, latch what must be latched, report the end."""
        summary = cycle.supervisor.freeze(end.status, end.reason)
        if self.machine.state in (MachineState.ACTIVE, MachineState.ARMED):
            self._disarm()
        if end.latch == STATE_FAULTED:
            self.fault = end.reason
        self.state = end.latch if end.latch is not None else STATE_IDLE
        if self.fault and self.state == STATE_IDLE:
            self.state = STATE_FAULTED  # disarming failed
        self.beat()
        head = self.ring.head
        self.emit(
            SessionEnded(
                time.monotonic(),
                cycle.sid,
                end.status,
                end.reason,
                summary,
                head - 1 if head > first_seq else -1,
                cycle.timing.stats(),
                STATES[self.state],
            )
        )
