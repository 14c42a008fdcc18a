"""The live machine's real-time side: a worker process runs the engine's loop at its rate
against a machine (:mod:`sessions.machine`), publishes full-rate telemetry into a shared-memory
ring (:mod:`.ring`), events over a non-blocking channel (:mod:`.channel`, :mod:`.messages`) and
its loop timing (:mod:`.timing`); the parent drives it through :class:`Worker` (:mod:`.handle`).

Data path: loop (:mod:`sessions.loop`) → worker (:mod:`.process`) → handle → server.
"""

from __future__ import annotations

from sessions.worker.handle import Worker, WorkerError, WorkerStatus
from sessions.worker.messages import (
    EStopped,
    Event,
    Faulted,
    LimitHit,
    RealtimeInfo,
    Rejected,
    ResetDone,
    SeekerEvaluation,
    SessionEnded,
    SessionStarted,
    Stopping,
    Timing,
    TimingStats,
    WorkerExited,
    WorkerLost,
    WorkerReady,
)
from sessions.worker.process import WorkerOptions
from sessions.worker.ring import COLUMNS, RingBatch, RingInfo, RingReader

__all__ = [
    "COLUMNS",
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
    "SeekerEvaluation",
    "SessionEnded",
    "SessionStarted",
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
