"""The pump: an asyncio task (100 Hz) that moves what the worker produces to the store and to
the live subscribers, and the only code that records a session.

    worker ring ──► pump ──► SessionRecorder (store, committed ≤ 1 s)
                        └──► LiveHub (WebSocket clients, the dashboard)
    worker events ─► pump ──► store (evaluations, events, the end) + LiveHub

When a session completes with a converged seeker, its optimum becomes the user's setpoint. A
worker that dies or stops beating ends the session ``aborted`` (its data stays) and the pump
notes the machine lost (:attr:`Pump.lost`) until the service attaches a new worker.

Protocol stages (:class:`~sessions.worker.StageBegun`) are stored as they come (an event, and a
phase row for a phase's first stage: :mod:`server.service.phases`) and published as ``stage``
frames; a phase's summary is computed from the store once its telemetry is stored, and every
phase still without one when the session has ended.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from typing import Any

import numpy as np

from server.service.live import LiveHub
from server.service.phases import record_stage, summarize_phases
from server.service.session import LiveSession
from sessions.codes import SessionStatus
from sessions.store import ConflictError, Store, StoreValueError
from sessions.summary import SessionSummary
from sessions.telemetry import RECORD_INDEX as RING
from sessions.telemetry import WIDTH
from sessions.worker import (
    CandidateMeasured,
    EStopped,
    Event,
    Faulted,
    LimitHit,
    Rejected,
    RingReader,
    SessionEnded,
    SessionStarted,
    StageBegun,
    Worker,
    WorkerLost,
)

log = logging.getLogger("ergoseek.pump")

PUMP_INTERVAL = 0.01  # s
EARLY_ROWS_MAX = 100_000  # ring rows kept while waiting for SessionStarted (100 s at 1 kHz)
BATCH = 50_000  # ring rows read at a time


class Pump:
    def __init__(self, store: Store, hub: LiveHub) -> None:
        self.store = store
        self.hub = hub
        self.worker: Worker | None = None
        self.reader: RingReader | None = None
        self.session: LiveSession | None = None  # the running session
        self.lost: str | None = None  # why the worker was lost (until a new one is attached)
        self._task: asyncio.Task[None] | None = None
        self._later: set[asyncio.Task[None]] = set()  # phase summaries waiting for their data

    # -- life ------------------------------------------------------------------------------------
    def attach(self, worker: Worker) -> None:
        """Follow this worker from now on (its ring from its newest record)."""
        if self.reader is not None:
            self.reader.close()
        self.worker = worker
        self.reader = worker.open_reader("now")
        self.lost = None

    def detach(self) -> None:
        """Follow no worker (the service is replacing it); :attr:`lost` stays until
        :meth:`attach`."""
        self.worker = None
        if self.reader is not None:
            self.reader.close()
            self.reader = None

    def start(self) -> None:
        self._task = asyncio.create_task(self._run(), name="ergoseek-pump")

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None

    def close(self) -> None:
        if self.reader is not None:
            self.reader.close()
            self.reader = None

    async def _run(self) -> None:
        while True:
            try:
                await self.pump_once()
            except asyncio.CancelledError:
                raise
            except Exception:  # the pump must outlive any one bad batch
                log.exception("pump")
            await asyncio.sleep(PUMP_INTERVAL)

    # -- one tick --------------------------------------------------------------------------------
    async def pump_once(self) -> None:
        worker = self.worker
        if worker is None:
            return
        events = worker.poll()
        try:
            self.drain_ring()
        finally:  # events are never lost to a bad batch of telemetry
            for ev in events:
                await self.handle(ev)

    def drain_ring(self) -> None:
        reader = self.reader
        if reader is None:
            return
        while True:
            batch = reader.read(max_records=BATCH)
            if not len(batch):
                return
            self.hub.publish_telemetry(batch.seq, batch.data, batch.missed)
            session = self.session
            if session is None:
                continue
            if session.worker_session is None:
                if sum(map(len, session.early)) < EARLY_ROWS_MAX:
                    session.early.append(batch.data.copy())
                continue
            self._record(session, batch.data)

    def _record(self, session: LiveSession, rows: np.ndarray) -> None:
        mine = rows[rows[:, RING["session"]] == session.worker_session]
        if len(mine):
            try:
                session.recorder.add_rows(mine[:, :WIDTH])
            except StoreValueError as exc:  # keep the session going; say what was refused
                log.warning("session %s: telemetry refused (%s)", session.db_id, exc)
            session.last_row = mine[-1]

    # -- events ----------------------------------------------------------------------------------
    async def handle(self, ev: Event) -> None:
        """Record a worker event (if it is the running session's) and publish it."""
        session = self.session
        frame: dict[str, Any] = {"type": "event", **ev.to_dict()}
        mine = session is not None and session.owns(ev)
        if mine:
            frame["db_session_id"] = session.db_id  # type: ignore[union-attr]
        if isinstance(ev, SessionStarted) and mine:
            self._started(session, ev)  # type: ignore[arg-type]
        elif isinstance(ev, Rejected) and session is not None:
            if ev.command == "start" and not session.started.is_set():
                session.rejected = ev.reason
                session.started.set()
        elif isinstance(ev, CandidateMeasured) and mine:
            self._evaluated(session, ev)  # type: ignore[arg-type]
            frame["type"] = "seeker"
        elif isinstance(ev, StageBegun) and mine:
            await self._staged(session, ev)  # type: ignore[arg-type]
            frame["type"] = "stage"
        elif isinstance(ev, LimitHit | EStopped | Faulted) and session is not None:
            self._note(session, ev)
        elif isinstance(ev, SessionEnded) and mine:
            self.drain_ring()
            self.hub.publish_last(ev.last_seq)  # the zero-torque record, to every client
            reason = None if ev.status == "completed" else ev.reason
            await self.finish(session, ev.status, ev.summary, reason)  # type: ignore[arg-type]
        elif isinstance(ev, WorkerLost):
            self.lost = ev.reason
            if session is not None:
                await self.finish(session, "aborted", None, ev.reason)
        self.hub.publish_event(frame)

    def _started(self, session: LiveSession, ev: SessionStarted) -> None:
        session.worker_session = ev.session
        for rows in session.early:
            self._record(session, rows)
        session.early.clear()
        session.started.set()

    def _evaluated(self, session: LiveSession, ev: CandidateMeasured) -> None:
        session.target, session.done = ev.target, ev.done
        session.evaluations += 1
        with contextlib.suppress(StoreValueError):
            session.recorder.add_evaluation(ev)

    async def _staged(self, session: LiveSession, ev: StageBegun) -> None:
        """A protocol stage began: stored, and the phase it ends summarized once stored."""
        stage = ev.stage
        before = session.stage
        session.stage = stage
        try:
            await asyncio.to_thread(
                record_stage, self.store, session.recorder, session.db_id, stage
            )
        except (StoreValueError, ConflictError) as exc:
            log.warning("session %s: stage not stored (%s)", session.db_id, exc)
            return
        if stage.segment == 0 and before is not None and before.phase != stage.phase:
            task = asyncio.create_task(self._summarize_when_stored(session, before.phase, stage))
            self._later.add(task)
            task.add_done_callback(self._later.discard)

    async def _summarize_when_stored(self, session: LiveSession, position: int, nxt: Any) -> None:
        """Summarize phase ``position`` once the next phase's first sample is stored (or the
        session has ended: then :meth:`finish` summarizes it). Not one period earlier: the
        stored telemetry's end would then cut the phase a period (or a rounding) short of
        where the next one begins."""
        dt = session.cfg.dt
        while not session.ended.is_set():
            stored = session.recorder.stored_until
            if stored is not None and stored >= nxt.start - 0.5 * dt:  # (on the 1/rate grid)
                break
            await asyncio.sleep(0.2)
        else:
            return
        try:
            await asyncio.to_thread(summarize_phases, self.store, session.db_id, [position])
        except Exception:  # a summary is derived data: recomputed when next asked for
            log.exception("session %s: phase %s not summarized", session.db_id, position)

    def _note(self, session: LiveSession, ev: LimitHit | EStopped | Faulted) -> None:
        """A limit hit, an e-stop or a fault: an event of the session, at its session time."""
        session_t = getattr(ev, "session_t", None)
        if session_t is None and session.last_row is not None:
            session_t = float(session.last_row[RING["t"]])
        detail = {k: v for k, v in ev.to_dict().items() if k not in ("kind", "t")}
        with contextlib.suppress(StoreValueError):
            session.recorder.add_event(session_t or 0.0, ev.kind, detail)

    async def finish(
        self,
        session: LiveSession,
        status: SessionStatus,
        summary: SessionSummary | None,
        reason: str | None,
    ) -> None:
        """The session's end, stored (and its optimum, if it converged, the user's setpoint)."""
        if self.session is session:
            self.session = None
        self.hub.session_id = None
        try:
            record = await asyncio.to_thread(
                session.recorder.finish, status, summary, abort_reason=reason
            )
        except ConflictError:
            record = None
        except Exception:
            log.exception("could not finish session %s", session.db_id)
            record = None
        if record is not None and status == "completed" and record.converged and record.optimum_w:
            with contextlib.suppress(ConflictError):
                await asyncio.to_thread(self.store.setpoints.from_session, session.db_id)
        try:
            await self._final_phases(session)
            self.hub.publish_event(
                {"type": "session_finished", "session_id": session.db_id, "status": status}
            )
        finally:  # (a shutdown waits for this: the live clients have seen the end by then)
            session.ended.set()

    async def _final_phases(self, session: LiveSession) -> None:
        """The session has ended: its open phase ends with its data; every phase summarized."""

        def final() -> None:
            span = self.store.telemetry.span(session.db_id)
            end = 0.0 if span.t1 is None else span.t1 + session.cfg.dt
            self.store.phases.close_open(session.db_id, end)
            summarize_phases(self.store, session.db_id)

        try:
            await asyncio.to_thread(final)
        except Exception:
            log.exception("session %s: phases not summarized", session.db_id)
