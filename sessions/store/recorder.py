"""The writer a running session feeds: telemetry rows, seeker evaluations and events go in
as they arrive; a background thread commits them every ``flush_interval`` (0.5 s by default)
in one short transaction, and at once after an event. Whatever was fed more than
``flush_interval`` (plus the commit's few milliseconds) before a crash is in the database.

Telemetry chunks span up to one second: the newest chunk stays *open* and is rewritten at
each flush until a sample arrives a second after its first, so chunks stay large (cheap to
read, well compressed) while no more than one flush interval is ever at risk. Each flush also
updates the session's live summary (duration, mean and peak τ·w, W(t) and its minimum,
evaluation count), which is what a session aborted by a crash keeps.

``add_*`` validate their input at once (raising :class:`~sessions.store.errors.StoreValueError`)
and only append to memory: they never wait for the database. A failed flush keeps its data
for the next attempt and sets :attr:`SessionRecorder.error`; :meth:`SessionRecorder.close`
and :meth:`SessionRecorder.finish` raise if the final flush fails.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import func, insert, select, update

from sessions.codes import SessionStatus
from sessions.store import validate as v
from sessions.store.database import Database
from sessions.store.errors import ConflictError, StoreError, StoreValueError
from sessions.store.models import Event, ExerciseSession, SeekerEvaluation, TelemetryChunk
from sessions.store.records import SessionRecord
from sessions.store.sessions import SessionRepository, evaluation_row, event_row, require_running
from sessions.store.timeseries import chunk_row, chunk_starts, columns_of
from sessions.summary import SessionSummary
from sessions.telemetry import INDEX, WIDTH

log = logging.getLogger(__name__)

_T, _W, _TAU, _WORK = 0, INDEX["w"], INDEX["tau"], INDEX["W"]


@dataclass(frozen=True, slots=True)
class LiveStats:
    """Running figures of the telemetry stored so far (finite samples only)."""

    count: int = 0
    power_sum: float = 0.0
    peak: float = 0.0
    work: float = 0.0
    work_min: float = 0.0
    t_last: float | None = None

    def add(self, cols: np.ndarray) -> LiveStats:
        if cols.shape[1] == 0:
            return self
        pm = cols[_TAU] * cols[_W]
        pm = pm[np.isfinite(pm)]
        work = cols[_WORK][np.isfinite(cols[_WORK])]
        return LiveStats(
            count=self.count + pm.size,
            power_sum=self.power_sum + float(pm.sum()),
            peak=max(self.peak, float(pm.max())) if pm.size else self.peak,
            work=float(work[-1]) if work.size else self.work,
            work_min=min(self.work_min, float(work.min())) if work.size else self.work_min,
            t_last=float(cols[_T, -1]),
        )

    def columns(self, dt: float) -> dict[str, float]:
        return {
            "duration": 0.0 if self.t_last is None else self.t_last + dt,
            "mean_power": self.power_sum / self.count if self.count else 0.0,
            "peak_power": self.peak,
            "work": self.work,
            "passivity_min": self.work_min,
        }


class SessionRecorder:
    """Feeds one running session into the store; one recorder per session.

    ``background=True`` (default): a daemon thread flushes every ``flush_interval`` seconds.
    ``background=False``: ``add_*`` flush inline once ``flush_interval`` has passed since the
    last flush (for batch imports and tests)."""

    def __init__(
        self,
        db: Database,
        session_id: int,
        *,
        flush_interval: float = 0.5,
        background: bool = True,
    ) -> None:
        self.session_id = session_id
        self.flush_interval = v.number("flush_interval", flush_interval, gt=0, le=1.0)
        self._db = db
        with db.session(write=False) as s:
            row = require_running(s, session_id)
            self._dt = 1.0 / float(row.config.get("rate", 1000.0))
            seq, t_last, samples = s.execute(
                select(func.max(TelemetryChunk.seq), func.max(TelemetryChunk.t1),
                       func.coalesce(func.sum(TelemetryChunk.n), 0))
                .where(TelemetryChunk.session_id == session_id)
            ).one()  # fmt: skip
            # Resuming a session that already holds data: continue after it.
            self._stats = LiveStats(
                count=int(samples),
                power_sum=row.mean_power * int(samples),
                peak=row.peak_power,
                work=row.work,
                work_min=row.passivity_min,
                t_last=t_last,
            )
        self._seq = 0 if seq is None else seq + 1
        self._open: np.ndarray | None = None  # columns of chunk self._seq, already stored
        self._last_t: float | None = t_last  # newest time accepted by add_*
        self._cols: list[np.ndarray] = []
        self._rows: list[Sequence[float]] = []
        self._evals: list[dict[str, Any]] = []
        self._events: list[dict[str, Any]] = []
        self._cond = threading.Condition()
        self._flush_lock = threading.Lock()
        self._urgent = False
        self._closing = False
        self._closed = False
        self._last_flush = time.monotonic()
        self.error: BaseException | None = None
        self._fatal: ConflictError | None = None
        self.flushes = 0
        self._thread: threading.Thread | None = None
        if background:
            self._thread = threading.Thread(
                target=self._run, name=f"store-recorder-{session_id}", daemon=True
            )
            self._thread.start()

    # -- feeding ---------------------------------------------------------------------------

    def add_row(self, row: Sequence[float]) -> None:
        """One telemetry sample: WIDTH values in the order of sessions.telemetry.CHANNELS."""
        if len(row) != WIDTH:
            raise StoreValueError("telemetry", f"expected {WIDTH} channels, got {len(row)}")
        t = row[0]
        with self._cond:
            self._check_open()
            last = self._last_t
            if not (isinstance(t, int | float) and math.isfinite(t) and t >= 0) or (
                last is not None and not t > last
            ):
                columns_of([row], after=last)  # raises the precise error
            self._rows.append(tuple(row))
            self._last_t = float(t)
        self._maybe_flush()

    def add_rows(self, rows: Any) -> None:
        """Telemetry samples: an array-like (n, WIDTH), in time order after those fed before."""
        with self._cond:
            self._check_open()
            cols = columns_of(rows, after=self._last_t)
            if cols.shape[1] == 0:
                return
            self._take_rows()
            self._cols.append(cols)
            self._last_t = float(cols[0, -1])
        self._maybe_flush()

    def add_evaluation(self, evaluation: Any) -> None:
        """A seeker evaluation (``t, candidate, power, stderr``), e.g. the loop's
        :class:`sessions.seekers.Evaluation`."""
        row = evaluation_row(self.session_id, evaluation)
        with self._cond:
            self._check_open()
            self._evals.append(row)
        self._maybe_flush()

    def add_evaluations(self, evaluations: Iterable[Any]) -> None:
        rows = [evaluation_row(self.session_id, ev) for ev in evaluations]
        with self._cond:
            self._check_open()
            self._evals.extend(rows)
        self._maybe_flush()

    def add_event(self, t: float, kind: str, detail: Mapping[str, Any] | None = None) -> None:
        """An event (``fault``, ``estop``, ``limit``…) at session time ``t``; flushed at once."""
        row = event_row(self.session_id, t, kind, detail)
        with self._cond:
            self._check_open()
            self._events.append(row)
            self._urgent = True
            self._cond.notify_all()
        if self._thread is None:
            self.flush()

    # -- writing ---------------------------------------------------------------------------

    def flush(self) -> None:
        """Commit everything fed so far in one transaction (no-op if nothing is pending)."""
        with self._flush_lock:
            with self._cond:
                self._take_rows()
                cols, evals, events = self._cols, self._evals, self._events
                self._cols, self._evals, self._events = [], [], []
            if not cols and not evals and not events:
                return
            try:
                self._write(cols, evals, events)
            except BaseException as exc:
                with self._cond:  # keep the data for the next attempt
                    self._cols[:0] = cols
                    self._evals[:0] = evals
                    self._events[:0] = events
                self.error = exc
                if isinstance(exc, ConflictError):
                    self._fatal = exc  # the session was ended elsewhere: no point retrying
                raise
            self.error = None
            self.flushes += 1
            self._last_flush = time.monotonic()

    def close(self) -> None:
        """Stop the background thread and flush what is left (raises if that fails). The
        session stays running: use :meth:`finish` to end it."""
        with self._cond:
            if self._closed:
                return
            self._closing = True
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join()
        self.flush()
        with self._cond:
            self._closed = True

    def finish(
        self,
        status: SessionStatus,
        summary: SessionSummary | Mapping[str, Any] | None = None,
        *,
        abort_reason: str | None = None,
    ) -> SessionRecord:
        """Flush, stop, and end the session with ``status`` and the engine's ``summary``
        (without one, the live figures become the summary)."""
        self.close()
        return SessionRepository(self._db).finish(
            self.session_id, status, summary, abort_reason=abort_reason
        )

    @property
    def stored_until(self) -> float | None:
        """Time of the newest sample committed."""
        return self._stats.t_last

    def __enter__(self) -> SessionRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- internals -------------------------------------------------------------------------

    def _check_open(self) -> None:
        if self._fatal is not None:
            raise self._fatal
        if self._closing:
            raise StoreError(f"recorder of session {self.session_id} is closed")

    def _take_rows(self) -> None:
        """Move single rows into the column buffer (caller holds the lock)."""
        if self._rows:
            self._cols.append(np.array(self._rows, dtype=np.float64).T.copy())
            self._rows = []

    def _maybe_flush(self) -> None:
        if self._thread is None and time.monotonic() - self._last_flush >= self.flush_interval:
            self.flush()

    def _write(
        self, cols: list[np.ndarray], evals: list[dict[str, Any]], events: list[dict[str, Any]]
    ) -> None:
        sid = self.session_id
        new = np.concatenate(cols, axis=1) if cols else np.empty((WIDTH, 0))
        stats = self._stats.add(new)
        data = new if self._open is None else np.concatenate((self._open, new), axis=1)
        pieces: list[np.ndarray] = []
        if data.shape[1]:
            starts = chunk_starts(data[0])
            ends = [*starts[1:], data.shape[1]]
            pieces = [data[:, a:b] for a, b in zip(starts, ends, strict=True)]
        inserts, updates = [], []
        for k, piece in enumerate(pieces):
            if k == 0 and self._open is not None:
                if piece.shape[1] != self._open.shape[1]:
                    updates.append(chunk_row(sid, self._seq, piece))
            else:
                inserts.append(chunk_row(sid, self._seq + k, piece))
        values: dict[str, Any] = stats.columns(self._dt)
        if evals:
            values["evaluation_count"] = ExerciseSession.evaluation_count + len(evals)
        with self._db.session(write=True) as s:
            done = s.execute(
                update(ExerciseSession)
                .where(ExerciseSession.id == sid, ExerciseSession.status == "running")
                .values(**values)
                .execution_options(synchronize_session=False)
            )
            if done.rowcount != 1:  # type: ignore[attr-defined]
                raise ConflictError(f"session {sid} is no longer running")
            if updates:
                s.execute(update(TelemetryChunk), updates)
            if inserts:
                s.execute(insert(TelemetryChunk), inserts)
            if evals:
                s.execute(insert(SeekerEvaluation), evals)
            if events:
                s.execute(insert(Event), events)
        self._stats = stats
        if pieces:
            self._seq += len(pieces) - 1
            self._open = pieces[-1].copy()

    def _run(self) -> None:
        while True:
            with self._cond:
                if not self._closing and not self._urgent:
                    self._cond.wait(self.flush_interval)
                self._urgent = False
                if self._closing:
                    return  # close() flushes the rest in its caller's thread
            try:
                self.flush()
            except ConflictError as exc:
                log.error("session %s: recording stopped: %s", self.session_id, exc)
                return
            except Exception as exc:
                log.warning("session %s: flush failed, will retry: %s", self.session_id, exc)
