"""Users: the people who exercise on the machine."""

from __future__ import annotations

from enum import Enum
from typing import Any

from pydantic import ValidationError
from sqlalchemy import func, select

from sessions.config import UserConfig, describe_validation_error
from sessions.store import validate as v
from sessions.store.database import Database
from sessions.store.errors import NotFoundError, StoreValueError
from sessions.store.models import User, utcnow
from sessions.store.records import Page, UserRecord


class _Unset(Enum):
    UNSET = "unset"


UNSET = _Unset.UNSET
"""Default of :meth:`UserRepository.update`'s fields: leave as is (None clears a field)."""


def page_bounds(limit: Any, offset: Any, *, max_limit: int = 1000) -> tuple[int, int]:
    return v.integer("limit", limit, ge=1, le=max_limit), v.integer("offset", offset, ge=0)


def _sim_profile(value: Any) -> dict[str, Any] | None:
    """A simulated person (:class:`sessions.config.UserConfig`), validated and normalised."""
    if value is None:
        return None
    if isinstance(value, UserConfig):
        return value.model_dump(mode="json")
    try:
        return UserConfig.model_validate(value).model_dump(mode="json")
    except ValidationError as exc:
        raise StoreValueError("sim_profile", describe_validation_error(exc)) from None


def _fields(
    name: Any, notes: Any, body_mass_kg: Any, limb: Any, sim_profile: Any = UNSET
) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if sim_profile is not UNSET:
        out["sim_profile"] = _sim_profile(sim_profile)
    if name is not UNSET:
        out["name"] = v.text("name", name, max_len=200)
    if notes is not UNSET:
        out["notes"] = v.text("notes", notes or "", max_len=10_000, allow_empty=True)
    if body_mass_kg is not UNSET:
        out["body_mass_kg"] = v.optional_number("body_mass_kg", body_mass_kg, gt=0, le=500)
    if limb is not UNSET:
        out["limb"] = v.optional_text("limb", limb, max_len=64)
    return out


def escape_like(text: str) -> str:
    return text.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_")


class UserRepository:
    def __init__(self, db: Database) -> None:
        self._db = db

    def create(
        self,
        name: str,
        *,
        notes: str = "",
        body_mass_kg: float | None = None,
        limb: str | None = None,
        sim_profile: UserConfig | dict[str, Any] | None = None,
    ) -> UserRecord:
        fields = _fields(name, notes, body_mass_kg, limb, sim_profile)
        with self._db.session(write=True) as s:
            now = utcnow()
            row = User(created_at=now, updated_at=now, **fields)
            s.add(row)
            s.flush()
            return UserRecord.model_validate(row)

    def get(self, user_id: int) -> UserRecord:
        with self._db.session(write=False) as s:
            row = s.get(User, user_id)
            if row is None:
                raise NotFoundError("user", user_id)
            return UserRecord.model_validate(row)

    def list(
        self, *, search: str | None = None, limit: int = 100, offset: int = 0
    ) -> Page[UserRecord]:
        """Users by name (then id); ``search`` matches part of the name, any case."""
        limit, offset = page_bounds(limit, offset)
        where = []
        if search:
            pattern = f"%{escape_like(v.text('search', search, max_len=200))}%"
            where.append(User.name.ilike(pattern, escape="\\"))
        with self._db.session(write=False) as s:
            total = s.scalar(select(func.count()).select_from(User).where(*where)) or 0
            rows = s.scalars(
                select(User).where(*where).order_by(User.name, User.id).limit(limit).offset(offset)
            )
            items = [UserRecord.model_validate(r) for r in rows]
        return Page[UserRecord](items=items, total=total, limit=limit, offset=offset)

    def update(
        self,
        user_id: int,
        *,
        name: str | _Unset = UNSET,
        notes: str | _Unset = UNSET,
        body_mass_kg: float | _Unset | None = UNSET,
        limb: str | _Unset | None = UNSET,
        sim_profile: UserConfig | dict[str, Any] | _Unset | None = UNSET,
    ) -> UserRecord:
        fields = _fields(name, notes, body_mass_kg, limb, sim_profile)
        with self._db.session(write=True) as s:
            row = s.get(User, user_id)
            if row is None:
                raise NotFoundError("user", user_id)
            for key, value in fields.items():
                setattr(row, key, value)
            row.updated_at = utcnow()
            s.flush()
            return UserRecord.model_validate(row)

    def delete(self, user_id: int) -> None:
        """Remove a user with all their sessions (and their data) and setpoints."""
        with self._db.session(write=True) as s:
            row = s.get(User, user_id)
            if row is None:
                raise NotFoundError("user", user_id)
            s.delete(row)
