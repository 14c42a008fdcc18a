"""Session phases: one row per phase of a session's protocol, written as the session runs.

A phase row is added when the phase begins (:meth:`PhaseRepository.begin`, which also ends
the phase before it at that time), so a crash loses no phase boundary; its summary (totals,
optimum, work intervals, profile fit: :mod:`sessions.protocol.analysis`) is written once its
telemetry is stored (:meth:`PhaseRepository.summarize`), also after the session has ended.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from sqlalchemy import select, update
from sqlalchemy.orm import Session as OrmSession

from sessions.codes import BOUNDS, PHASE_KINDS
from sessions.protocol.analysis import PhaseResult
from sessions.store import validate as v
from sessions.store.database import Database
from sessions.store.errors import NotFoundError
from sessions.store.models import ExerciseSession, SessionPhase
from sessions.store.records import PhaseRecord
from sessions.store.sessions import require_running

MAX_POSITION = 1000


def _phases(s: OrmSession, session_id: int) -> list[PhaseRecord]:
    rows = s.scalars(
        select(SessionPhase)
        .where(SessionPhase.session_id == session_id)
        .order_by(SessionPhase.position)
    )
    return [PhaseRecord.model_validate(r) for r in rows]


class PhaseRepository:
    def __init__(self, db: Database) -> None:
        self._db = db

    def begin(
        self,
        session_id: int,
        position: int,
        kind: str,
        name: str,
        t_start: float,
        *,
        planned_end: float | None = None,
        detail: Mapping[str, Any] | None = None,
    ) -> PhaseRecord:
        """Phase ``position`` of a running session began at ``t_start``; any phase still open
        before it ends then. (Beginning a phase already stored updates it: idempotent.)"""
        values = {
            "kind": v.choice("kind", kind, PHASE_KINDS),
            "name": v.text("name", name, max_len=100, allow_empty=True),
            "t_start": v.number("t_start", t_start, ge=0),
            "planned_end": v.optional_number("planned_end", planned_end, ge=0),
            "detail": v.json_object("detail", detail),
        }
        position = v.integer("position", position, ge=0, le=MAX_POSITION)
        with self._db.session(write=True) as s:
            require_running(s, session_id)
            s.execute(
                update(SessionPhase)
                .where(
                    SessionPhase.session_id == session_id,
                    SessionPhase.position != position,
                    SessionPhase.t_end.is_(None),
                )
                .values(t_end=values["t_start"])
                .execution_options(synchronize_session=False)
            )
            row = s.scalar(
                select(SessionPhase).where(
                    SessionPhase.session_id == session_id, SessionPhase.position == position
                )
            )
            if row is None:
                row = SessionPhase(session_id=session_id, position=position, **values)
                s.add(row)
            else:
                for key, value in values.items():
                    setattr(row, key, value)
            s.flush()
            return PhaseRecord.model_validate(row)

    def close_open(self, session_id: int, t_end: float) -> list[int]:
        """End every phase of the session still open at ``t_end`` (the session's end);
        returns their positions."""
        t_end = v.number("t_end", t_end, ge=0)
        with self._db.session(write=True) as s:
            self._exists(s, session_id)
            rows = s.scalars(
                select(SessionPhase).where(
                    SessionPhase.session_id == session_id, SessionPhase.t_end.is_(None)
                )
            ).all()
            for row in rows:
                row.t_end = max(t_end, row.t_start)
            return [r.position for r in rows]

    def summarize(self, session_id: int, result: PhaseResult) -> PhaseRecord:
        """Store a phase's summary (its span as the telemetry shows it, totals, detail)."""
        values = {
            "t_end": v.number("end", result.end, ge=0),
            "mean_power": v.number("mean_power", result.mean_power),
            "peak_power": v.number("peak_power", result.peak_power),
            "work": v.number("work", result.work),
            "mean_w": v.number("mean_w", result.mean_w),
            "optimum_w": v.optional_number("optimum_w", result.optimum_w, gt=0),
            "at_bound": (
                None if result.at_bound is None else v.choice("at_bound", result.at_bound, BOUNDS)
            ),
            "detail": v.json_object("detail", result.detail),
        }
        with self._db.session(write=True) as s:
            self._exists(s, session_id)
            row = s.scalar(
                select(SessionPhase).where(
                    SessionPhase.session_id == session_id,
                    SessionPhase.position == result.index,
                )
            )
            if row is None:
                raise NotFoundError("phase", (session_id, result.index))
            for key, value in values.items():
                setattr(row, key, value)
            s.flush()
            return PhaseRecord.model_validate(row)

    def list(self, session_id: int) -> list[PhaseRecord]:
        with self._db.session(write=False) as s:
            self._exists(s, session_id)
            return _phases(s, session_id)

    @staticmethod
    def _exists(s: OrmSession, session_id: int) -> None:
        if s.get(ExerciseSession, session_id) is None:
            raise NotFoundError("session", session_id)
