"""A user's progress across sessions: per session, what it found and produced (the optimum
first found and at the end, peak and mean power, work) and the velocity-spectrum fits of its
profile phases, oldest first. Two queries, whatever the number of sessions."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import select

from sessions.codes import SessionStatus
from sessions.store import validate as v
from sessions.store.database import Database
from sessions.store.errors import NotFoundError
from sessions.store.models import ExerciseSession, SessionPhase, User
from sessions.store.records import ProgressPoint, ProgressRecord

PROFILE_KEYS = ("tau0", "wmax", "pmax", "w_opt", "a")


def profile_summary(detail: dict[str, Any]) -> dict[str, Any] | None:
    """The fitted parameters of a profile phase (without its curve and step means)."""
    fit = detail.get("profile")
    if not isinstance(fit, dict):
        return None
    return {"model": fit.get("model"), **{k: fit.get(k) for k in PROFILE_KEYS}}


class ProgressRepository:
    def __init__(self, db: Database) -> None:
        self._db = db

    def user(
        self,
        user_id: int,
        *,
        since: datetime | None = None,
        until: datetime | None = None,
        statuses: tuple[SessionStatus, ...] = ("completed", "stopped"),
        limit: int = 500,
    ) -> ProgressRecord:
        """The user's ended sessions with one of ``statuses``, started in [since, until)."""
        limit = v.integer("limit", limit, ge=1, le=5000)
        S = ExerciseSession
        where: list[Any] = [S.user_id == user_id, S.status.in_(statuses)]
        if since is not None:
            where.append(S.started_at >= v.moment("since", since))
        if until is not None:
            where.append(S.started_at < v.moment("until", until))
        with self._db.session(write=False) as s:
            user = s.get(User, user_id)
            if user is None:
                raise NotFoundError("user", user_id)
            rows = s.scalars(
                select(S).where(*where).order_by(S.started_at.desc(), S.id.desc()).limit(limit)
            ).all()[::-1]
            ids = [r.id for r in rows]
            profiles: dict[int, list[dict[str, Any]]] = {}
            if ids:
                for sid, detail in s.execute(
                    select(SessionPhase.session_id, SessionPhase.detail)
                    .where(SessionPhase.session_id.in_(ids), SessionPhase.kind == "profile")
                    .order_by(SessionPhase.session_id, SessionPhase.position)
                ):
                    fit = profile_summary(detail)
                    if fit is not None:
                        profiles.setdefault(sid, []).append(fit)
            points = [_point(r, profiles.get(r.id, [])) for r in rows]
            return ProgressRecord(user_id=user_id, body_mass_kg=user.body_mass_kg, sessions=points)


def _point(r: ExerciseSession, profiles: list[dict[str, Any]]) -> ProgressPoint:
    protocol = (r.config or {}).get("protocol") or {}
    return ProgressPoint(
        session_id=r.id, started_at=r.started_at, status=r.status,  # type: ignore[arg-type]
        protocol=protocol.get("name") or "", seeker=r.seeker, converged=r.converged,
        at_bound=r.at_bound, optimum_w=r.optimum_w, optimum_p=r.optimum_p, optimum_t=r.optimum_t,
        wd_converged=r.wd_converged, t_converged=r.t_converged, mean_power=r.mean_power,
        peak_power=r.peak_power, work=r.work, duration=r.duration, profiles=profiles,
    )  # fmt: skip
