"""Sessions: start, finish, list and read back, with their seeker evaluations and events.

A session is ``running`` from :meth:`SessionRepository.start` until
:meth:`SessionRepository.finish` sets one of the final statuses. Evaluations, events and
telemetry are accepted only while it runs. After a crash, :meth:`SessionRepository.recover`
(called once by the server on start, before any recorder exists) marks the sessions left
running as ``aborted``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import func, select, update
from sqlalchemy.orm import Session as OrmSession

from sessions.codes import END_STATUSES, STATUSES, SessionStatus
from sessions.store import validate as v
from sessions.store.database import Database
from sessions.store.errors import ConflictError, NotFoundError, StoreValueError
from sessions.store.models import (
    Account,
    Event,
    ExerciseSession,
    SeekerEvaluation,
    SessionPhase,
    User,
    utcnow,
)
from sessions.store.records import (
    EvaluationRecord,
    EventRecord,
    Page,
    PhaseRecord,
    SessionDetail,
    SessionRecord,
)
from sessions.store.users import page_bounds
from sessions.summary import SessionSummary

RESTART_REASON = "server restarted"
SEARCH_FIGURES = (
    "at_bound",
    "optimum_t",
    "t_converged",
    "wd_converged",
    "p_converged",
    "target_min",
    "target_max",
    "regret",
)  # the summary's search figures, each a column of its own (issue 14)


def evaluation_row(session_id: int, ev: Any, field: str = "evaluation") -> dict[str, Any]:
    """A seeker evaluation (``t, candidate, power, stderr`` attributes, e.g.
    :class:`sessions.seekers.Evaluation`) as a row; an infinite stderr is stored as NULL."""
    try:
        t, candidate, power = ev.t, ev.candidate, ev.power
        stderr = getattr(ev, "stderr", None)
    except AttributeError as exc:
        raise StoreValueError(field, f"not an evaluation ({exc})") from None
    if stderr is not None:
        if isinstance(stderr, float) and stderr == math.inf:
            stderr = None
        else:
            stderr = v.number(f"{field}.stderr", stderr, ge=0)
    return {
        "session_id": session_id,
        "t": v.number(f"{field}.t", t, ge=0),
        "candidate": v.number(f"{field}.candidate", candidate),
        "power": v.number(f"{field}.power", power),
        "stderr": stderr,
    }


def event_row(session_id: int, t: Any, kind: Any, detail: Any) -> dict[str, Any]:
    return {
        "session_id": session_id,
        "t": v.number("t", t, ge=0),
        "kind": v.identifier("kind", kind),
        "detail": v.json_object("detail", detail),
        "created_at": utcnow(),
    }


def require_running(s: OrmSession, session_id: int, *, lock: bool = False) -> ExerciseSession:
    """The session, if it is running; ``lock`` holds its row until the transaction ends
    (PostgreSQL; a SQLite writer holds the whole database already)."""
    row = s.get(ExerciseSession, session_id, with_for_update=lock or None)
    if row is None:
        raise NotFoundError("session", session_id)
    if row.status != "running":
        raise ConflictError(f"session {session_id} is {row.status}, not running")
    return row


def _statuses(status: str | Sequence[str] | None) -> list[str]:
    if status is None:
        return []
    values = [status] if isinstance(status, str) else list(status)
    return [v.choice("status", x, STATUSES) for x in values]


class SessionRepository:
    def __init__(self, db: Database) -> None:
        self._db = db

    def start(
        self,
        user_id: int,
        config: Any,
        *,
        backend: str = "simulation",
        account_id: int | None = None,
        started_at: datetime | None = None,
    ) -> SessionRecord:
        """A new running session for ``user_id`` with ``config`` (a
        :class:`~sessions.config.SessionConfig` or its JSON), validated and stored whole."""
        data = v.config(config)
        backend = v.identifier("backend", backend)
        when = utcnow() if started_at is None else v.moment("started_at", started_at)
        with self._db.session(write=True) as s:
            if s.get(User, user_id) is None:
                raise NotFoundError("user", user_id)
            if account_id is not None and s.get(Account, account_id) is None:
                raise NotFoundError("account", account_id)
            row = ExerciseSession(
                user_id=user_id,
                account_id=account_id,
                backend=backend,
                config=data,
                status="running",
                started_at=when,
                seeker=data["seeker"]["kind"],
                converged=False,
                mean_power=0.0,
                peak_power=0.0,
                work=0.0,
                duration=0.0,
                passivity_min=0.0,
                evaluation_count=0,
            )
            s.add(row)
            s.flush()
            return SessionRecord.model_validate(row)

    def get(self, session_id: int) -> SessionRecord:
        with self._db.session(write=False) as s:
            row = s.get(ExerciseSession, session_id)
            if row is None:
                raise NotFoundError("session", session_id)
            return SessionRecord.model_validate(row)

    def list(
        self,
        *,
        user_id: int | None = None,
        status: SessionStatus | Sequence[SessionStatus] | None = None,
        since: datetime | None = None,
        until: datetime | None = None,
        account_id: int | None = None,
        limit: int = 50,
        offset: int = 0,
    ) -> Page[SessionRecord]:
        """Sessions newest first (start time, then id): those of ``user_id``, with one of the
        ``status`` values, started at or after ``since`` and before ``until``."""
        limit, offset = page_bounds(limit, offset)
        where: list[Any] = []
        if user_id is not None:
            where.append(ExerciseSession.user_id == user_id)
        if account_id is not None:
            where.append(ExerciseSession.account_id == account_id)
        statuses = _statuses(status)
        if statuses:
            where.append(ExerciseSession.status.in_(statuses))
        if since is not None:
            where.append(ExerciseSession.started_at >= v.moment("since", since))
        if until is not None:
            where.append(ExerciseSession.started_at < v.moment("until", until))
        with self._db.session(write=False) as s:
            total = s.scalar(select(func.count()).select_from(ExerciseSession).where(*where))
            rows = s.scalars(
                select(ExerciseSession)
                .where(*where)
                .order_by(ExerciseSession.started_at.desc(), ExerciseSession.id.desc())
                .limit(limit)
                .offset(offset)
            )
            items = [SessionRecord.model_validate(r) for r in rows]
        return Page[SessionRecord](items=items, total=total or 0, limit=limit, offset=offset)

    def running(self) -> list[SessionRecord]:
        with self._db.session(write=False) as s:
            rows = s.scalars(
                select(ExerciseSession)
                .where(ExerciseSession.status == "running")
                .order_by(ExerciseSession.id)
            )
            return [SessionRecord.model_validate(r) for r in rows]

    def evaluations(self, session_id: int) -> list[EvaluationRecord]:
        with self._db.session(write=False) as s:
            self._exists(s, session_id)
            return self._evaluations(s, session_id)

    def events(self, session_id: int, *, kind: str | None = None) -> list[EventRecord]:
        with self._db.session(write=False) as s:
            self._exists(s, session_id)
            return self._events(s, session_id, kind)

    def detail(self, session_id: int) -> SessionDetail:
        """The session's summary, evaluations, events and phases, read in one snapshot."""
        with self._db.session(write=False) as s:
            row = s.get(ExerciseSession, session_id)
            if row is None:
                raise NotFoundError("session", session_id)
            return SessionDetail(
                session=SessionRecord.model_validate(row),
                evaluations=self._evaluations(s, session_id),
                events=self._events(s, session_id, None),
                phases=[
                    PhaseRecord.model_validate(r)
                    for r in s.scalars(
                        select(SessionPhase)
                        .where(SessionPhase.session_id == session_id)
                        .order_by(SessionPhase.position)
                    )
                ],
            )

    def add_evaluation(self, session_id: int, evaluation: Any) -> EvaluationRecord:
        data = evaluation_row(session_id, evaluation)
        with self._db.session(write=True) as s:
            require_running(s, session_id)
            row = SeekerEvaluation(**data)
            s.add(row)
            s.execute(
                update(ExerciseSession)
                .where(ExerciseSession.id == session_id)
                .values(evaluation_count=ExerciseSession.evaluation_count + 1)
            )
            s.flush()
            return EvaluationRecord.model_validate(row)

    def add_event(
        self, session_id: int, t: float, kind: str, detail: Mapping[str, Any] | None = None
    ) -> EventRecord:
        data = event_row(session_id, t, kind, detail)
        with self._db.session(write=True) as s:
            require_running(s, session_id)
            row = Event(**data)
            s.add(row)
            s.flush()
            return EventRecord.model_validate(row)

    def finish(
        self,
        session_id: int,
        status: SessionStatus,
        summary: SessionSummary | Mapping[str, Any] | None = None,
        *,
        abort_reason: str | None = None,
        ended_at: datetime | None = None,
    ) -> SessionRecord:
        """End a running session with a final ``status`` and the engine's ``summary`` (without
        one, the live figures stay). :class:`ConflictError` if it is not running."""
        status = v.choice("status", status, END_STATUSES)  # type: ignore[assignment]
        values: dict[str, Any] = {"status": status}
        reason = abort_reason
        if summary is not None:
            sm = v.summary(summary)
            values.update(
                optimum_w=sm.optimum_w,
                optimum_p=sm.optimum_p,
                converged=sm.converged,
                mean_power=sm.mean_power,
                peak_power=sm.peak_power,
                work=sm.work,
                duration=sm.duration,
                passivity_min=sm.passivity_min,
                evaluation_count=sm.evaluations,
                abort_reason=None,
                **{name: getattr(sm, name) for name in SEARCH_FIGURES},
            )
            if sm.seeker:
                values["seeker"] = v.identifier("summary.seeker", sm.seeker)
            if reason is None:
                reason = sm.abort_reason
        if reason is not None:
            values["abort_reason"] = v.text("abort_reason", reason, max_len=1000)
        values["ended_at"] = utcnow() if ended_at is None else v.moment("ended_at", ended_at)
        with self._db.session(write=True) as s:
            row = require_running(s, session_id, lock=True)
            if values["ended_at"] < row.started_at:
                raise StoreValueError("ended_at", "before the session started")
            for key, value in values.items():
                setattr(row, key, value)
            s.flush()
            return SessionRecord.model_validate(row)

    def recover(self, reason: str = RESTART_REASON) -> list[int]:
        """Mark every session left ``running`` as ``aborted`` with ``reason``, ending it when
        its stored data ends; their data stays. Call once on start, before any recorder."""
        reason = v.text("reason", reason, max_len=1000)
        with self._db.session(write=True) as s:
            rows = s.execute(
                select(ExerciseSession.id, ExerciseSession.started_at, ExerciseSession.duration)
                .where(ExerciseSession.status == "running")
                .order_by(ExerciseSession.id)
            ).all()
            for sid, started, duration in rows:
                s.execute(
                    update(ExerciseSession)
                    .where(ExerciseSession.id == sid, ExerciseSession.status == "running")
                    .values(
                        status="aborted",
                        abort_reason=reason,
                        ended_at=started + timedelta(seconds=max(duration, 0.0)),
                    )
                )
            return [sid for sid, _, _ in rows]

    def delete(self, session_id: int) -> None:
        """Remove a session with its evaluations, telemetry and events (a setpoint it
        produced stays, without its source)."""
        with self._db.session(write=True) as s:
            row = s.get(ExerciseSession, session_id)
            if row is None:
                raise NotFoundError("session", session_id)
            s.delete(row)

    @staticmethod
    def _exists(s: OrmSession, session_id: int) -> None:
        if s.get(ExerciseSession, session_id) is None:
            raise NotFoundError("session", session_id)

    @staticmethod
    def _evaluations(s: OrmSession, session_id: int) -> list[EvaluationRecord]:
        rows = s.scalars(
            select(SeekerEvaluation)
            .where(SeekerEvaluation.session_id == session_id)
            .order_by(SeekerEvaluation.t, SeekerEvaluation.id)
        )
        return [EvaluationRecord.model_validate(r) for r in rows]

    @staticmethod
    def _events(s: OrmSession, session_id: int, kind: str | None) -> list[EventRecord]:
        q = select(Event).where(Event.session_id == session_id)
        if kind is not None:
            q = q.where(Event.kind == kind)
        rows = s.scalars(q.order_by(Event.t, Event.id))
        return [EventRecord.model_validate(r) for r in rows]
