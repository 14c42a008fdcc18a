"""The worker's safety decisions for one session, in the order they act, and the controlled
stop they start.

What ends a session, and how (:class:`End`):
- **e-stop** (command): zero torque written the same cycle the command is seen, drive
  disarmed, latched (state ``estopped``) until a reset; the session ends ``stopped`` (reason
  ``e-stop``): an operator's decision, like a stop.
- **machine fault** (timeout, garbage, drive error, a non-finite measurement): the backend
  has already written zero torque; the session ends ``faulted``; latched until a reset.
- **a non-finite value in the loop** (reference, estimate, command, power, work, target) or
  **a stall** longer than the catch-up bound (a free-running machine): zero torque at once,
  the session ends ``aborted`` naming the value or the stall; nothing is latched (the machine
  is sound), and the summary keeps only what is finite.
- **parent gone** (the command pipe closes or the parent pid changes), **SIGTERM**, **shutdown**:
  zero torque at once, the session ends ``aborted`` (``stopped`` for a shutdown).
- **velocity over the limit** and **passivity breach** (W < −c²): a controlled stop, the
  session ends ``aborted``.
- **duration reached** or **the protocol over**: a controlled stop, ``completed``. **Stop**
  (command): controlled, ``stopped`` (or at once with ``immediate``, or when a stop is
  already under way).

A controlled stop that the session asks for (the duration reached, the operator's stop) first
brings the handle to rest: the loop's reference winds down to zero velocity under control
(the protocol's closing stop, :meth:`sessions.loop.Loop.wind_down`), the person asked to relax;
once the handle is still (``Loop.finished``; a protocol that ends with its cool-down gets
there by itself) the torque is ramped out. Never a disarm at speed. The session's result is
frozen when the torque ramp begins: the wind-down is part of the session (its closing phase).

The controlled stop (:class:`StopRamp`) is a stop category 1, after IEC 60204-1: the motor
stays under control while its torque is taken away, then the drive is disabled.

- The torque ramps linearly from the last command to zero over ``duration`` (a person leaning
  on the handle is not dropped at once).
- The motor never drives during a stop: a ramp value that would push the handle along its
  motion (u·w > 0) is replaced by zero; only resisting torque remains.
- The velocity governor of the loop (:class:`sessions.limits.Limits`) still brakes above the
  machine's velocity limit, and the torque clamp still holds.
- The stop is over when the ramp has reached zero and the handle is within the velocity limit,
  or at the latest ``duration + grace`` seconds after it began.

The e-stop is not this: it writes zero torque at once (stop category 0). The torque clamp is
the engine's (:mod:`sessions.limits`) and the machine's own.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Protocol

from sessions.codes import (
    FLAG_ESTOP,
    FLAG_PASSIVITY,
    STATE_ESTOPPED,
    STATE_FAULTED,
    TORQUE_LIMIT,
    VELOCITY_LIMIT,
    EndStatus,
)
from sessions.limits import Limits
from sessions.loop import Loop
from sessions.machine import Machine
from sessions.summary import SessionSummary, summarize
from sessions.worker.messages import (
    EStop,
    EStopped,
    Faulted,
    LimitHit,
    Rejected,
    Reset,
    Shutdown,
    StartSession,
    Stop,
    Stopping,
)


@dataclass(frozen=True)
class End:
    """How a session ended, and the state the worker latches afterwards (None: idle)."""

    status: EndStatus
    reason: str
    latch: int | None = None


class Host(Protocol):
    """What the supervisor needs of the worker process."""

    machine: Machine
    terminated: bool
    shutdown: bool
    exit_reason: str

    def emit(self, ev: object) -> None: ...

    def enter_stopping(self) -> None: ...


class StopRamp:
    __slots__ = ("done", "k", "limits", "max_steps", "steps", "u0")

    def __init__(
        self, u0: float, duration: float, dt: float, limits: Limits, grace: float = 2.0
    ) -> None:
        self.u0 = u0
        self.steps = max(1, round(duration / dt))
        self.max_steps = self.steps + round(grace / dt)
        self.k = 0
        self.limits = limits
        self.done = False

    def command(self, w: float) -> float:
        """The torque for this period, given the measured velocity."""
        k = self.k + 1
        self.k = k
        s = 1.0 - k / self.steps
        u = self.u0 * s if s > 0.0 else 0.0
        if u * w > 0.0:
            u = 0.0
        u = self.limits.apply(u, w)
        if u * w > 0.0:  # the governor only brakes; keep it that way
            u = 0.0
        if (s <= 0.0 and abs(w) <= self.limits.max_velocity) or k >= self.max_steps:
            self.done = True
            u = 0.0
        return u


class Supervisor:
    """Decides, every cycle, whether the session goes on, stops under control or ends now.

    ``summary`` is the session's result, frozen once: when a stop begins (the ramp does not
    change what the session found) or when it ends without one."""

    __slots__ = (
        "host", "loop", "sid", "n_steps", "ramp_s", "ramp", "stop_end", "summary", "prev_flags",
        "ending",
    )  # fmt: skip

    def __init__(self, host: Host, loop: Loop, sid: str, n_steps: int, ramp_s: float) -> None:
        self.host = host
        self.loop = loop
        self.sid = sid
        self.n_steps = n_steps
        self.ramp_s = ramp_s
        self.ramp: StopRamp | None = None
        self.stop_end: End | None = None
        self.summary: SessionSummary | None = None
        self.prev_flags = 0
        self.ending: End | None = None  # winding down to rest, then this end

    def freeze(self, status: EndStatus, reason: str) -> SessionSummary:
        """The session's summary, computed the first time only. If the loop's figures are
        not finite (the loop met a non-finite value), what is finite is kept."""
        if self.summary is None:
            why = None if status == "completed" else reason
            try:
                self.summary = summarize(self.loop, why)
            except ValueError:  # a non-finite figure: SessionSummary refuses it
                self.summary = partial_summary(self.loop, why)
        return self.summary

    # -- between cycles: what the operator and the process ask ------------------------------
    def command(self, cmd: object, now: float) -> tuple[End | None, int]:
        """A command that arrived during the session: (how it ends the session, flags)."""
        host = self.host
        if isinstance(cmd, EStop):
            host.machine.zero()
            zero_at = time.monotonic()
            host.emit(EStopped(zero_at, self.sid, zero_at))
            return End("stopped", "e-stop", STATE_ESTOPPED), FLAG_ESTOP
        if isinstance(cmd, Stop):
            if cmd.immediate or self.ramp is not None or self.ending is not None:
                host.machine.zero()
                return End("stopped", cmd.reason or "stopped at once by the operator"), 0
            self.wind_down("stopped", cmd.reason or "stopped by the operator")
        elif isinstance(cmd, Shutdown):
            host.machine.zero()
            host.shutdown = True
            host.exit_reason = "shutdown"
            return End("stopped", "worker shut down"), 0
        elif isinstance(cmd, StartSession):
            host.emit(Rejected(now, "start", "a session is running"))
        elif isinstance(cmd, Reset):
            host.emit(Rejected(now, "reset", "a session is running; stop it first"))
        return None, 0

    def upstream(self) -> End | None:
        """SIGTERM or the parent gone: zero torque now, the session ends aborted."""
        host = self.host
        if not host.terminated:
            return None
        host.machine.zero()
        host.exit_reason = host.exit_reason or "terminated (SIGTERM)"
        return End("aborted", host.exit_reason)

    def fault(self, reason: str, now: float) -> End:
        """The machine failed (it has zeroed the torque itself, best effort)."""
        self.host.emit(Faulted(now, self.sid, reason))
        self.freeze("faulted", reason)
        return End("faulted", reason, STATE_FAULTED)

    def loop_error(self, reason: str, measured: bool, now: float) -> End:
        """This period cannot go on (the cycle has zeroed the torque): a non-finite
        measurement is the machine's fault (latched); a non-finite value of the loop's own, or
        a stall beyond the catch-up bound, ends the session aborted."""
        if measured:
            return self.fault(reason, now)
        self.freeze("aborted", reason)
        return End("aborted", reason)

    # -- after each step: what the physics says -------------------------------------------
    def check(self, u: float, w: float, now: float) -> int:
        """Limit events, then the soft limits and the duration; returns flags to add."""
        loop = self.loop
        lf = loop.flags
        if lf != self.prev_flags:
            self._limit_events(lf, u, w, now)
        if lf & VELOCITY_LIMIT:
            vmax = loop.limits.max_velocity
            self.begin_stop(
                "aborted", f"velocity over the limit: |w| = {abs(w):.2f} > {vmax:g} rad/s", u
            )
        elif loop.passivity.breached:
            p = loop.passivity
            self.host.emit(LimitHit(now, self.sid, loop.row[0], "passivity", p.work))
            self.begin_stop(
                "aborted", f"passivity breached: W = {p.work:.3g} J < -c² = {-p.c2:g} J", u
            )
            return FLAG_PASSIVITY
        elif loop.finished:
            end = self.ending or End("completed", "protocol finished")
            self.begin_stop(end.status, end.reason, u)
        elif loop.k >= self.n_steps and self.ending is None:
            self.wind_down("completed", "duration reached")
        return 0

    def _limit_events(self, lf: int, u: float, w: float, now: float) -> None:
        prev, t, emit = self.prev_flags, self.loop.row[0], self.host.emit
        if lf & TORQUE_LIMIT and not prev & TORQUE_LIMIT:
            emit(LimitHit(now, self.sid, t, "torque", abs(u)))
        if lf & VELOCITY_LIMIT and not prev & VELOCITY_LIMIT:
            emit(LimitHit(now, self.sid, t, "velocity", abs(w)))
        self.prev_flags = lf

    def wind_down(self, status: EndStatus, reason: str) -> None:
        """Bring the handle to rest; the torque ramp follows once it is still (:meth:`check`)."""
        self.ending = End(status, reason)
        self.host.enter_stopping()
        self.host.emit(Stopping(time.monotonic(), self.sid, reason))
        self.loop.wind_down()

    def begin_stop(self, status: EndStatus, reason: str, u0: float | None = None) -> None:
        """Freeze the session's result and start the controlled stop (once)."""
        if self.ramp is not None:
            return
        self.freeze(status, reason)
        self.stop_end = End(status, reason)
        host = self.host
        host.enter_stopping()
        if self.ending is None:  # (a wind-down has said so already)
            host.emit(Stopping(time.monotonic(), self.sid, reason))
        u = host.machine.last_command if u0 is None else u0
        loop = self.loop
        self.ramp = StopRamp(u, self.ramp_s, loop.dt, loop.limits)


def partial_summary(loop: Loop, reason: str | None) -> SessionSummary:
    """A summary of what is finite when the loop's own figures are not."""
    seeker = loop.seeker
    finite = [v if math.isfinite(v) else 0.0 for v in (loop.mean_power, loop.peak_power)]
    work, w_min = loop.passivity.work, loop.passivity.minimum
    return SessionSummary(
        converged=False,
        seeker=seeker.kind,
        mean_power=finite[0],
        peak_power=finite[1],
        work=work if math.isfinite(work) else 0.0,
        duration=loop.elapsed,
        passivity_min=min(0.0, w_min) if math.isfinite(w_min) else 0.0,
        evaluations=len(seeker.evaluations),
        abort_reason=reason,
    )
