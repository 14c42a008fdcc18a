"""What crosses the process boundary between the worker and its parent: plain frozen data.

Commands go parent → worker over a pipe; events come back worker → parent over a non-blocking
channel (:mod:`sessions.worker.channel`). Every event has a ``kind`` and ``to_dict()`` (JSON-ready:
what the web server forwards to the dashboard).

Sessions carry two identifiers: ``session_id``, the caller's tag for the session (a string the
caller chooses: the server passes its database id), and ``session``, the worker's own session
number (the ring's ``session`` column). They are never compared with each other.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

from sessions.codes import EndStatus, WorkerStateName
from sessions.config import SessionConfig
from sessions.protocol.stage import Stage
from sessions.summary import SessionSummary


# -- commands (parent → worker) -----------------------------------------------------------------
@dataclass(frozen=True)
class StartSession:
    cfg: SessionConfig
    session_id: str


@dataclass(frozen=True)
class Stop:
    """End the session: a controlled stop (torque ramped out), or at once with ``immediate``;
    ``reason`` says who asked (default: the operator)."""

    immediate: bool = False
    reason: str | None = None


@dataclass(frozen=True)
class EStop:
    """Zero torque at once, drive disabled, latched until :class:`Reset`."""


@dataclass(frozen=True)
class Reset:
    """Clear a latched e-stop or fault. Never starts anything. ``sent_ns``: when it was asked
    (CLOCK_MONOTONIC): a reset asked before the e-stop it would clear is refused (the e-stop
    line overtakes the command pipe, a reset queued there must not undo it)."""

    sent_ns: int = 0


@dataclass(frozen=True)
class Shutdown:
    """Zero torque, disarm, close the machine, exit."""


Command = StartSession | Stop | EStop | Reset | Shutdown


# -- plain data carried by events -----------------------------------------------------------------
@dataclass(frozen=True)
class TimingStats:
    """Loop timing over a session so far. Lateness: how far behind its deadline a cycle woke
    (µs). Compute: from wake-up to the torque written and the record published (µs)."""

    rate_hz: float = 0.0
    cycles: int = 0
    missed: int = 0  # whole periods skipped because a cycle woke a period or more late
    missed_ratio: float = 0.0  # missed / (cycles + missed)
    p50_us: float = 0.0
    p99_us: float = 0.0
    p999_us: float = 0.0
    max_us: float = 0.0
    compute_p50_us: float = 0.0
    compute_p99_us: float = 0.0
    compute_max_us: float = 0.0
    overruns: int = 0  # cycles whose compute took longer than a period


@dataclass(frozen=True)
class RealtimeInfo:
    """What the worker obtained from the OS (it degrades quietly when something is refused)."""

    cpu: int | None = None  # pinned to this CPU
    sched_fifo: bool = False
    priority: int = 0
    timer_slack_ns: int | None = None
    notes: tuple[str, ...] = ()


# -- events (worker → parent) ---------------------------------------------------------------------
@dataclass(frozen=True)
class Event:
    kind: ClassVar[str] = "event"
    t: float  # monotonic time the worker emitted it

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind}
        for f in dataclasses.fields(self):
            out[f.name] = _plain(getattr(self, f.name))
        return out


@dataclass(frozen=True)
class WorkerReady(Event):
    kind: ClassVar[str] = "ready"
    pid: int
    machine: str
    realtime: RealtimeInfo
    fault: str | None = None  # the machine could not be connected


@dataclass(frozen=True)
class SessionStarted(Event):
    kind: ClassVar[str] = "session_started"
    session_id: str  # the caller's tag
    session: int  # the worker's session number (ring column "session")
    first_seq: int  # ring sequence number of the session's first record
    rate_hz: float
    duration: float


@dataclass(frozen=True)
class CandidateMeasured(Event):
    """The seeker has measured one candidate (not to be confused with the store's table of
    evaluations, which records these)."""

    kind: ClassVar[str] = "evaluation"
    session_id: str
    session_t: float  # session time at the end of the measurement, s
    candidate: float  # rad/s
    power: float  # W
    stderr: float
    target: float  # the seeker's next target (or final answer when done)
    done: bool
    bracket_lo: float = math.nan  # the bracket the seeker now holds the optimum in, rad/s
    bracket_hi: float = math.nan
    fraction: float = 0.0  # progress of the search, 0 … 1


@dataclass(frozen=True)
class StageBegun(Event):
    """A segment of the session's protocol has begun (``stage.segment == 0``: a new phase)."""

    kind: ClassVar[str] = "stage"
    session_id: str
    stage: Stage


@dataclass(frozen=True)
class LimitHit(Event):
    kind: ClassVar[str] = "limit"
    session_id: str
    session_t: float
    limit: Literal["torque", "velocity", "passivity"]
    value: float  # |u| N·m, |w| rad/s, or W J


@dataclass(frozen=True)
class Stopping(Event):
    kind: ClassVar[str] = "stopping"
    session_id: str
    reason: str


@dataclass(frozen=True)
class SessionEnded(Event):
    kind: ClassVar[str] = "session_ended"
    session_id: str
    status: EndStatus
    reason: str
    summary: SessionSummary
    last_seq: int  # ring sequence number of the session's last record (-1: none)
    timing: TimingStats = field(default_factory=TimingStats)
    state_after: WorkerStateName = "idle"  # idle, or latched: estopped / faulted


@dataclass(frozen=True)
class EStopped(Event):
    kind: ClassVar[str] = "estop"
    session_id: str | None
    zero_at: float  # monotonic time zero torque was written


@dataclass(frozen=True)
class Faulted(Event):
    kind: ClassVar[str] = "fault"
    session_id: str | None
    reason: str


@dataclass(frozen=True)
class ResetDone(Event):
    kind: ClassVar[str] = "reset"
    fault: str | None = None  # the reset itself failed: still faulted


@dataclass(frozen=True)
class Rejected(Event):
    kind: ClassVar[str] = "rejected"
    command: str
    reason: str


@dataclass(frozen=True)
class Timing(Event):
    kind: ClassVar[str] = "timing"
    session_id: str
    stats: TimingStats


@dataclass(frozen=True)
class WorkerExited(Event):
    kind: ClassVar[str] = "exited"
    reason: str


@dataclass(frozen=True)
class WorkerLost(Event):
    """Made by the parent, not the worker: the worker died or stopped beating."""

    kind: ClassVar[str] = "lost"
    reason: str
    exitcode: int | None


def _plain(value: Any) -> Any:
    if isinstance(value, SessionSummary):
        return value.model_dump()
    if isinstance(value, Stage):
        return value.to_dict()
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
