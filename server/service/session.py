"""The running session as the web process follows it: the database record it is written to,
the tag the worker knows it by, the worker's session number once it has started, and what
the dashboard and the API show of it."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field

import numpy as np

from sessions.config import SessionConfig
from sessions.protocol.stage import Stage
from sessions.store import SessionRecorder
from sessions.worker import Event


@dataclass(frozen=True)
class ActiveSession:
    """A snapshot of the running session: plain data for the dashboard."""

    session_id: int  # the database id
    user_id: int
    cfg: SessionConfig
    target: float | None = None
    done: bool = False
    stage: Stage | None = None


@dataclass(eq=False)
class LiveSession:
    db_id: int  # the store's id of the session
    user_id: int
    cfg: SessionConfig
    recorder: SessionRecorder
    worker_session: int | None = None  # the worker's own number, from SessionStarted
    started: asyncio.Event = field(default_factory=asyncio.Event)
    rejected: str | None = None
    ended: asyncio.Event = field(default_factory=asyncio.Event)
    target: float | None = None
    done: bool = False
    evaluations: int = 0
    last_row: np.ndarray | None = None
    stage: Stage | None = None  # the protocol stage running now
    # Ring rows read before the worker's SessionStarted event was: the loop may run a few
    # periods before the pump sees the event; they are recorded once it does.
    early: list[np.ndarray] = field(default_factory=list)

    @property
    def tag(self) -> str:
        """What the worker calls this session (``session_id`` of its events): the database
        id, as the caller's string tag. Events are matched on it, never on a number."""
        return str(self.db_id)

    def owns(self, ev: Event) -> bool:
        """Whether a worker event is about this session."""
        return getattr(ev, "session_id", None) == self.tag

    def snapshot(self) -> ActiveSession:
        return ActiveSession(self.db_id, self.user_id, self.cfg, self.target, self.done, self.stage)
