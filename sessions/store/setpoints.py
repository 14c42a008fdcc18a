"""Setpoints: a user's optimal velocity (and the power there), one row per finding. The
user's current setpoint is the newest accepted one; rejected findings stay in the history."""

from __future__ import annotations

from datetime import datetime

from sqlalchemy import select

from sessions.store import validate as v
from sessions.store.database import Database
from sessions.store.errors import ConflictError, NotFoundError, StoreValueError
from sessions.store.models import ExerciseSession, Setpoint, User, utcnow
from sessions.store.records import SetpointRecord

MANUAL = "manual"


class SetpointRepository:
    def __init__(self, db: Database) -> None:
        self._db = db

    def record(
        self,
        user_id: int,
        velocity: float,
        *,
        power: float | None = None,
        seeker: str = MANUAL,
        session_id: int | None = None,
        accepted: bool = True,
        created_at: datetime | None = None,
    ) -> SetpointRecord:
        """A new setpoint: ``velocity`` in rad/s (> 0), ``power`` in W measured there (None if
        not measured), found by ``seeker`` (``manual`` when a trainer set it), from
        ``session_id`` (a session of the same user)."""
        values = {
            "user_id": user_id,
            "velocity": v.number("velocity", velocity, gt=0),
            "power": v.optional_number("power", power),
            "seeker": v.identifier("seeker", seeker),
            "session_id": session_id,
            "accepted": v.flag("accepted", accepted),
            "created_at": utcnow() if created_at is None else v.moment("created_at", created_at),
        }
        with self._db.session(write=True) as s:
            if s.get(User, user_id) is None:
                raise NotFoundError("user", user_id)
            if session_id is not None:
                source = s.get(ExerciseSession, session_id)
                if source is None:
                    raise NotFoundError("session", session_id)
                if source.user_id != user_id:
                    raise StoreValueError("session_id", f"session {session_id} is another user's")
            row = Setpoint(**values)
            s.add(row)
            s.flush()
            return SetpointRecord.model_validate(row)

    def from_session(self, session_id: int, *, accepted: bool = True) -> SetpointRecord:
        """The optimum a finished session found, recorded as its user's setpoint."""
        with self._db.session(write=True) as s:  # record() joins this transaction
            src = s.get(ExerciseSession, session_id)
            if src is None:
                raise NotFoundError("session", session_id)
            if src.status == "running":
                raise ConflictError(f"session {session_id} is still running")
            if src.optimum_w is None:
                raise ConflictError(f"session {session_id} found no optimum")
            return self.record(
                src.user_id,
                src.optimum_w,
                power=src.optimum_p,
                seeker=src.seeker or MANUAL,
                session_id=session_id,
                accepted=accepted,
            )

    def set_accepted(self, setpoint_id: int, accepted: bool) -> SetpointRecord:
        accepted = v.flag("accepted", accepted)
        with self._db.session(write=True) as s:
            row = s.get(Setpoint, setpoint_id)
            if row is None:
                raise NotFoundError("setpoint", setpoint_id)
            row.accepted = accepted
            s.flush()
            return SetpointRecord.model_validate(row)

    def history(self, user_id: int, *, accepted_only: bool = False) -> list[SetpointRecord]:
        """The user's setpoints, newest first."""
        q = select(Setpoint).where(Setpoint.user_id == user_id)
        if accepted_only:
            q = q.where(Setpoint.accepted.is_(True))
        with self._db.session(write=False) as s:
            if s.get(User, user_id) is None:
                raise NotFoundError("user", user_id)
            rows = s.scalars(q.order_by(Setpoint.created_at.desc(), Setpoint.id.desc()))
            return [SetpointRecord.model_validate(r) for r in rows]

    def current(self, user_id: int) -> SetpointRecord | None:
        """The newest accepted setpoint; None if the user has none."""
        with self._db.session(write=False) as s:
            if s.get(User, user_id) is None:
                raise NotFoundError("user", user_id)
            row = s.scalar(
                select(Setpoint)
                .where(Setpoint.user_id == user_id, Setpoint.accepted.is_(True))
                .order_by(Setpoint.created_at.desc(), Setpoint.id.desc())
                .limit(1)
            )
            return None if row is None else SetpointRecord.model_validate(row)
