"""One live session, one period at a time, as ros2_control's node thread does it::

    wait (pacer) → commands → read → step → supervise → write → publish

- **wait**: :class:`sessions.worker.pacer.Pacer` (sleep, then spin, to the deadline);
- **commands** (the e-stop line in the ring's header, every period; the command pipe) and
  the process's own state (SIGTERM, the parent gone): the supervisor may end the session at
  once; the cycle then writes its last record (zero torque) and returns;
- **read** the machine, **step** the engine's loop (or, during a controlled stop, the stop
  ramp), **supervise** (limits, passivity, duration: :mod:`sessions.worker.supervisor`),
  **write** the torque;
- **publish**: the record into the shared-memory ring, the heartbeat, the timing; events
  (a seeker evaluation, a protocol stage begun, limit hits, a Timing a second) go out over
  the channel.

A machine fault at read or write ends the session ``faulted`` (the backend has zeroed the
torque).

Missed periods: on a free-running machine (a real drive: the plant moves on its own clock and
the drive holds the last torque), a cycle that wakes m whole periods late first steps the loop
through the m periods it missed (a bounded catch-up, at most ``catch_up_max`` of them), with
the measurement interpolated between the last read and this one and the torque the drive held
(:meth:`SessionCycle.catch_up`), so that the RISE integrals, the observer, the filters, W(t) and
the session's duration all see the time that really passed; a longer stall ends the session
(zero torque, ``aborted``). The simulator advances one period per write: nothing to catch up.

A non-finite value never goes further than where it appears: a NaN or infinite
measurement (angle, velocity, a torque sensor's reading) is a fault of the machine (zero
torque, ``faulted``, latched) and never enters the loop; a non-finite value the loop computes
(reference, torque estimate, command, power, work, target) zeroes the torque and ends the
session ``aborted``, naming the value. Nothing here allocates more than short-lived floats
and tuples.
"""

from __future__ import annotations

import math
import os
import time
from typing import TYPE_CHECKING

from sessions.codes import FLAG_CATCHUP, FLAG_FAULT, FLAG_STOPPING, STOPPING
from sessions.config import SessionConfig
from sessions.loop import Loop
from sessions.machine import MachineError
from sessions.worker.messages import CandidateMeasured, EStop, StageBegun, Timing
from sessions.worker.pacer import Pacer, TimingRecorder
from sessions.worker.ring import H_CYCLES, H_ESTOP, H_HEARTBEAT
from sessions.worker.supervisor import End, Supervisor

if TYPE_CHECKING:
    from sessions.worker.process import WorkerProcess

PARENT_CHECK_MASK = 7  # look at the parent pid every 8 cycles (a syscall)
# the loop's values checked each period, in causal order: (row index, what it is)
LOOP_VALUES = ((3, "reference wd"), (4, "reference acceleration ad"), (6, "torque estimate τ"),
               (5, "torque command u"), (7, "power p"), (8, "work W"), (9, "target γ"))  # fmt: skip


class LoopError(Exception):
    """This period cannot go on: zero torque now. ``measured``: the machine's fault (latched)."""

    measured = False


class NonFiniteError(LoopError):
    """A non-finite value in this period: ``measured`` (the machine's) or the loop's own."""

    def __init__(self, what: str, value: float, measured: bool) -> None:
        super().__init__(f"non-finite {'measured ' if measured else ''}{what} = {value!r}")
        self.measured = measured


class StalledError(LoopError):
    """The worker missed more periods than the loop may catch up."""

    def __init__(self, late: float, bound: float) -> None:
        super().__init__(
            f"the loop stalled {late * 1e3:.0f} ms (more than catch_up_max = {bound * 1e3:.0f} "
            "ms): the controller lost track of the handle"
        )


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
        self.period = loop.dt
        self.catch_up_max = opt.catch_up_max if host.machine.free_running else -1.0
        self.prev = (loop.row[1], loop.row[2], math.nan)  # the last measurement (q, w, τ)

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
        sensor = host.machine.has_torque_sensor  # else τ reads NaN by design
        catching = self.catch_up_max >= 0.0  # a free-running plant: missed periods are real
        period = self.period
        next_timing = mono() + self.timing_interval
        for stage in self.loop.reference.log:  # the first stage, begun with the loop
            host.emit(StageBegun(mono(), self.sid, stage))
        pacer.start()
        while True:
            now, late = pacer.wait()
            self.cycles = cycles = self.cycles + 1
            ready = poll(0)
            if (
                ready
                or host.terminated
                or not cycles & PARENT_CHECK_MASK
                or hdr[H_ESTOP] != host.estop_seen
            ):
                end, flags = self.commands(now, cycles, bool(ready))
                if end is not None:
                    return self.last_record(end, flags, late, now)
            try:
                q, w, tau = read()
                if q - q != 0.0 or w - w != 0.0 or (sensor and tau - tau != 0.0):  # NaN, ±inf
                    raise_measurement(q, w, tau)
                if late >= period and catching:
                    self.catch_up(q, w, tau, now, late)
                u = self.update(q, w, tau, now)
                write(u)
            except MachineError as exc:
                end = sup.fault(str(exc), mono())
                return self.last_record(end, FLAG_FAULT, late, now)
            except LoopError as exc:
                host.machine.zero()
                end = sup.loop_error(str(exc), exc.measured, mono())
                return self.last_record(end, FLAG_FAULT, late, now)
            self.prev = (q, w, tau)
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
        if host.estop_requested():  # the e-stop line, before anything the pipe holds
            return self.stop_now(*sup.command(EStop(), now))
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
        return self.stop_now(end, flags)

    def stop_now(self, end: End | None, flags: int) -> tuple[End | None, int]:
        if end is not None:
            self.supervisor.freeze(end.status, end.reason)
        return end, flags

    def update(
        self, q: float, w: float, tau: float, now: float, held: float | None = None
    ) -> float:
        """This period's torque: the loop's, supervised, or the stop ramp's (``held``: a
        missed period, over which the drive held that torque)."""
        loop, sup = self.loop, self.supervisor
        ramp = sup.ramp
        if ramp is None:
            u = loop.step(q, w, tau, held)
            row = self.row = loop.row
            s = u + row[3] + row[4] + row[6] + row[7] + row[8] + row[9]
            if s - s != 0.0:  # one of them is NaN or ±inf (or their sum overflowed)
                check_loop_values(u, row)
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

    def catch_up(self, q: float, w: float, tau: float, now: float, late: float) -> None:
        """Step the loop through the periods the worker missed (bounded), each with the
        measurement interpolated between the last read and this one, and the torque the
        drive held meanwhile; each is recorded (flag ``caught up``) at the deadline it had
        (``mono``) and how late it was stepped (``late``)."""
        period = self.period
        m = int(late / period)  # as many as the pacer skipped
        if m * period > self.catch_up_max:
            raise StalledError(late, self.catch_up_max)
        qp, wp, tp = self.prev
        held = self.host.machine.last_command
        rwrite, sid = self.host.ring.write, self.session
        first = now - late  # the deadline of the first period missed
        for i in range(m):
            f = (i + 1) / (m + 1)
            self.update(qp + (q - qp) * f, wp + (w - wp) * f, tp + (tau - tp) * f, now, held)
            at = first + i * period
            flags = float(self.flags | FLAG_CATCHUP)
            rwrite((*self.row, held, self.phase, flags, (now - at) * 1e6, at, sid, self.stage))

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


def raise_measurement(q: float, w: float, tau: float) -> None:
    """Name the non-finite measurement (the caller found one)."""
    for what, value in (("angle q", q), ("velocity w", w), ("torque τ", tau)):
        if not math.isfinite(value):
            raise NonFiniteError(what, value, measured=True)


def check_loop_values(u: float, row: tuple[float, ...]) -> None:
    """Raise :class:`NonFiniteError` for the first non-finite value of this step, if any."""
    for i, what in LOOP_VALUES:
        value = u if i == 5 else row[i]
        if not math.isfinite(value):
            raise NonFiniteError(what, value, measured=False)
