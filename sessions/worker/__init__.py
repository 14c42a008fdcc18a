"""The live machine's real-time side: a worker process runs the engine's loop at its rate
against a machine (:mod:`sessions.machine`); the parent drives it through :class:`Worker`.

    process     the worker's life: connect, wait for commands, run sessions, exit safe
    cycle       one session, one period at a time: read → step → supervise → write → publish
    pacer       the deadlines (sleep, then spin), the OS's real-time settings, loop timing
    supervisor  the safety decisions and the controlled stop
    ring        full-rate records in shared memory (one writer, readers anywhere)
    messages    commands and events: plain frozen data across the process boundary
    channel     the worker's non-blocking event pipe
    handle      the parent's side: :class:`Worker`, its liveness check
    options     how the worker runs (:class:`WorkerOptions`)

Data path: loop (:mod:`sessions.loop`) → worker (:mod:`.cycle`) → ring and events → handle →
server.
"""

from __future__ import annotations

from sessions.worker.handle import Worker, WorkerError, WorkerStatus
from sessions.worker.messages import (
    CandidateMeasured,
    EStopped,
    Event,
    Faulted,
    LimitHit,
    RealtimeInfo,
    Rejected,
    ResetDone,
    SessionEnded,
    SessionStarted,
    StageBegun,
    Stopping,
    Timing,
    TimingStats,
    WorkerExited,
    WorkerLost,
    WorkerReady,
)
from sessions.worker.options import WorkerOptions
from sessions.worker.ring import COLUMNS, RingBatch, RingInfo, RingReader

__all__ = [
    "COLUMNS",
    "CandidateMeasured",
    "EStopped",
    "Event",
    "Faulted",
    "LimitHit",
    "RealtimeInfo",
    "Rejected",
    "ResetDone",
    "RingBatch",
    "RingInfo",
    "RingReader",
    "SessionEnded",
    "SessionStarted",
    "StageBegun",
    "Stopping",
    "Timing",
    "TimingStats",
    "Worker",
    "WorkerError",
    "WorkerExited",
    "WorkerLost",
    "WorkerOptions",
    "WorkerReady",
    "WorkerStatus",
]
