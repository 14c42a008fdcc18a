"""One live session, one period at a time, as ros2_control's node thread does it::

    wait (pacer) → commands → read → step → supervise → write → publish

- **wait**: :class:`sessions.worker.pacer.Pacer` (sleep, then spin, to the deadline);
- **commands** and the process's own state (SIGTERM, the parent gone): the supervisor may end
  the session at once; the cycle then writes its last record (zero torque) and returns;
- **read** the machine, **step** the engine's loop (or, during a controlled stop, the stop
  ramp), **supervise** (limits, passivity, duration: :mod:`sessions.worker.supervisor`),
  **write** the torque;
- **publish**: the record into the shared-memory ring, the heartbeat, the timing; events
  (a seeker evaluation, a protocol stage begun, limit hits, a Timing a second) go out over
  the channel.

A machine fault at read or write ends the session ``faulted`` (the backend has zeroed the
torque). Nothing here allocates more than short-lived floats and tuples.
"""

from __future__ import annotations

import math
import os
import time
from typing import TYPE_CHECKING

from sessions.codes import FLAG_FAULT, FLAG_STOPPING, STOPPING
from sessions.config import SessionConfig
from sessions.loop import Loop
from sessions.machine import MachineError
from sessions.worker.messages import CandidateMeasured, StageBegun, Timing
from sessions.worker.pacer import Pacer, TimingRecorder
from sessions.worker.ring import H_CYCLES, H_HEARTBEAT
from sessions.worker.supervisor import End, Supervisor

if TYPE_CHECKING:
    from sessions.worker.process import WorkerProcess

PARENT_CHECK_MASK = 7  # look at the parent pid every 8 cycles (a syscall)


class SessionCycle:
    """Runs one session's cycles until it ends (:meth:`run` returns how)."""

    def __init__(self, host: WorkerProcess, loop: Loop, cfg: SessionConfig, sid: str) -> None:
        self.host = host
        self.loop = loop
        self.sid = sid
        self.session = float(host.session_no)  # the ring's session column
        opt = host.opt
        self.pacer = Pacer(cfg.rate, opt.spin_us * 1e-6)
        self.supervisor = Supervisor(host, loop, sid, round(cfg.duration * cfg.rate), opt.stop_ramp)
        self.timing_interval = opt.timing_interval
        self.cycles = 0
        self.row = loop.row  # the last record's engine channels
        self.phase = 0.0
        self.flags = 0
        self.stage = float(loop.stage)

    @property
    def timing(self) -> TimingRecorder:
        return self.pacer.timing

    def run(self) -> End:
        host, sup, pacer = self.host, self.supervisor, self.pacer
        read, write = host.machine.read, host.machine.write
        ring, hdr, events = host.ring, host.ring.hdr, host.events
        rwrite, mono, mono_ns = ring.write, time.monotonic, time.monotonic_ns
        record = pacer.timing.record
        poll = host.cmd_poll.poll
        next_timing = mono() + self.timing_interval
        for stage in self.loop.reference.log:  # the first stage, begun with the loop
            host.emit(StageBegun(mono(), self.sid, stage))
        pacer.start()
        while True:
            now, late = pacer.wait()
            self.cycles = cycles = self.cycles + 1
            ready = poll(0)
            if ready or host.terminated or not cycles & PARENT_CHECK_MASK:
                end, flags = self.commands(now, cycles, bool(ready))
                if end is not None:
                    return self.last_record(end, flags, late, now)
            try:
                q, w, tau = read()
                u = self.update(q, w, tau, now)
                write(u)
            except MachineError as exc:
                end = sup.fault(str(exc), mono())
                return self.last_record(end, FLAG_FAULT, late, now)
            rwrite(
                (*self.row, u, self.phase, float(self.flags), late * 1e6, now, self.session,
                 self.stage)
            )  # fmt: skip
            hdr[H_HEARTBEAT] = mono_ns()
            hdr[H_CYCLES] = cycles
            record(late, mono() - now)
            ramp = sup.ramp
            if ramp is not None and ramp.done:
                assert sup.stop_end is not None
                return sup.stop_end
            if now >= next_timing:
                next_timing += self.timing_interval
                host.emit(Timing(now, self.sid, pacer.timing.stats()))
            if events.pending:
                events.flush()

    def commands(self, now: float, cycles: int, ready: bool) -> tuple[End | None, int]:
        """A pending command (``ready``), then the process's own state: how the session ends
        now, if it does, and the flags of its last record. (Called only when there is
        something to look at: a command, SIGTERM, or the parent check every 8 cycles.)"""
        host, sup = self.host, self.supervisor
        end, flags = None, 0
        if ready:
            try:
                end, flags = sup.command(host.cmds.recv(), now)
            except (EOFError, OSError):
                host.terminated = True
                host.exit_reason = "parent died (command pipe closed)"
        if (cycles & PARENT_CHECK_MASK) == 0 and os.getppid() != host.parent_pid:
            host.terminated = True
            host.exit_reason = "parent died"
        if end is None:
            end = sup.upstream()
        if end is not None:
            sup.freeze(end.status, end.reason)
        return end, flags

    def update(self, q: float, w: float, tau: float, now: float) -> float:
        """This period's torque: the loop's, supervised, or the stop ramp's."""
        loop, sup = self.loop, self.supervisor
        ramp = sup.ramp
        if ramp is None:
            u = loop.step(q, w, tau)
            self.row = loop.row
            self.phase = float(loop.seeker.phase)
            self.stage = float(loop.stage)
            if loop.evaluation is not None:
                self.evaluated(now)
            stage = loop.reference.changed
            if stage is not None:
                self.host.emit(StageBegun(now, self.sid, stage))
            self.flags = loop.flags | sup.check(u, w, now)
            return u
        u = ramp.command(w)
        seeker, nan = loop.seeker, math.nan
        t = (loop.k + ramp.k - 1) * loop.dt
        self.row = (t, q, w, nan, nan, u, nan, nan, loop.passivity.work, seeker.target)
        self.phase = float(STOPPING)
        self.flags = FLAG_STOPPING | loop.limits.flags
        return u

    def evaluated(self, now: float) -> None:
        """The seeker has just measured a candidate: tell the parent."""
        ev, seeker = self.loop.evaluation, self.loop.seeker
        assert ev is not None
        lo, hi = seeker.bracket
        self.host.emit(
            CandidateMeasured(
                now, self.sid, ev.t, ev.candidate, ev.power, ev.stderr,
                seeker.target, seeker.done, lo, hi, seeker.fraction(),
            )
        )  # fmt: skip

    def last_record(self, end: End, flags: int, late: float, now: float) -> End:
        """The cycle that wrote zero torque: one period after the last record, u = 0."""
        row = self.row
        self.host.ring.write(
            (row[0] + self.loop.dt, *row[1:5], 0.0, *row[6:], 0.0, float(STOPPING), float(flags),
             late * 1e6, now, self.session, self.stage)
        )  # fmt: skip
        return end
