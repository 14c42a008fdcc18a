"""Protocol templates: named protocols (:class:`sessions.protocol.config.Protocol`) a trainer
keeps for the next session, private to their owner or shared with every account.

Who may do what (the API maps refusals to 403/404; checked here so every caller obeys):

- **read**: shared templates, and one's own; an administrator reads all;
- **create**: a trainer (or administrator), private or shared;
- **edit, delete**: one's own templates, and the shared ones (a team's templates are the team's);
  an administrator any; only the owner or an administrator changes whether one is shared.

A template one may not read is "not found" (its existence is not disclosed). Names are unique
among one owner's templates and among the shared ones (409 otherwise).
"""

from __future__ import annotations

from typing import Any

from pydantic import ValidationError
from sqlalchemy import func, or_, select
from sqlalchemy.orm import Session as OrmSession

from sessions.codes import RANK, Role
from sessions.config import validation_problems
from sessions.protocol.config import Protocol
from sessions.store import validate as v
from sessions.store.database import Database
from sessions.store.errors import ConflictError, NotFoundError, StoreError, StoreValueError
from sessions.store.models import Account, ProtocolTemplate, utcnow
from sessions.store.records import TemplateRecord

_T = ProtocolTemplate


class ForbiddenError(StoreError, PermissionError):
    """The account may read this but not change it."""


def protocol_json(value: Any, field: str = "protocol") -> dict[str, Any]:
    """A protocol, validated, as the JSON the store keeps."""
    if isinstance(value, Protocol):
        return value.model_dump(mode="json")
    try:
        return Protocol.model_validate(value).model_dump(mode="json")
    except ValidationError as exc:
        key, reason = validation_problems(exc)[0]
        raise StoreValueError(f"{field}.{key}" if key != "scenario" else field, reason) from None


def _admin(role: Role) -> bool:
    return RANK[role] >= RANK["admin"]


def _readable(account_id: int, role: Role) -> Any:
    return None if _admin(role) else or_(_T.shared.is_(True), _T.account_id == account_id)


class TemplateRepository:
    def __init__(self, db: Database) -> None:
        self._db = db

    def create(
        self,
        account_id: int,
        name: str,
        protocol: Any,
        *,
        description: str = "",
        shared: bool = False,
    ) -> TemplateRecord:
        values = {
            "name": v.text("name", name, max_len=100),
            "description": v.text("description", description, max_len=2000, allow_empty=True),
            "protocol": protocol_json(protocol),
            "shared": v.flag("shared", shared),
        }
        with self._db.session(write=True) as s:
            if s.get(Account, account_id) is None:
                raise NotFoundError("account", account_id)
            self._unique(s, values["name"], account_id, values["shared"], None)
            now = utcnow()
            row = _T(account_id=account_id, created_at=now, updated_at=now, **values)
            s.add(row)
            s.flush()
            return TemplateRecord.model_validate(row)

    def get(self, template_id: int, *, account_id: int, role: Role) -> TemplateRecord:
        with self._db.session(write=False) as s:
            return TemplateRecord.model_validate(self._readable(s, template_id, account_id, role))

    def list(
        self, *, account_id: int, role: Role, search: str | None = None
    ) -> list[TemplateRecord]:
        """The templates the account may read: shared first, then its own, by name."""
        where = [w for w in (_readable(account_id, role),) if w is not None]
        if search:
            where.append(
                func.lower(_T.name).contains(v.text("search", search, max_len=100).lower())
            )
        with self._db.session(write=False) as s:
            rows = s.scalars(
                select(_T).where(*where).order_by(_T.shared.desc(), _T.name, _T.id)
            ).all()
            return [TemplateRecord.model_validate(r) for r in rows]

    def update(
        self,
        template_id: int,
        *,
        account_id: int,
        role: Role,
        name: str | None = None,
        protocol: Any = None,
        description: str | None = None,
        shared: bool | None = None,
    ) -> TemplateRecord:
        values: dict[str, Any] = {}
        if name is not None:
            values["name"] = v.text("name", name, max_len=100)
        if description is not None:
            values["description"] = v.text("description", description, max_len=2000,
                                           allow_empty=True)  # fmt: skip
        if protocol is not None:
            values["protocol"] = protocol_json(protocol)
        if shared is not None:
            values["shared"] = v.flag("shared", shared)
        with self._db.session(write=True) as s:
            row = self._editable(s, template_id, account_id, role)
            if "shared" in values and values["shared"] != row.shared:
                if row.account_id != account_id and not _admin(role):
                    raise ForbiddenError("only its owner or an administrator shares or unshares it")
            if "name" in values or "shared" in values:
                self._unique(s, values.get("name", row.name), row.account_id,
                             values.get("shared", row.shared), row.id)  # fmt: skip
            for key, value in values.items():
                setattr(row, key, value)
            row.updated_at = utcnow()
            s.flush()
            return TemplateRecord.model_validate(row)

    def delete(self, template_id: int, *, account_id: int, role: Role) -> None:
        with self._db.session(write=True) as s:
            s.delete(self._editable(s, template_id, account_id, role))

    # -- rules ---------------------------------------------------------------------------
    @staticmethod
    def _readable(s: OrmSession, template_id: int, account_id: int, role: Role) -> _T:
        row = s.get(_T, template_id)
        if row is None or not (_admin(role) or row.shared or row.account_id == account_id):
            raise NotFoundError("protocol template", template_id)
        return row

    def _editable(self, s: OrmSession, template_id: int, account_id: int, role: Role) -> _T:
        row = self._readable(s, template_id, account_id, role)
        if RANK[role] < RANK["trainer"]:
            raise ForbiddenError("needs the trainer role")
        return row

    @staticmethod
    def _unique(s: OrmSession, name: str, owner: int | None, shared: bool, me: int | None) -> None:
        scope = _T.shared.is_(True) if shared else (_T.shared.is_(False) & (_T.account_id == owner))
        clash = s.scalar(
            select(_T.id).where(scope, func.lower(_T.name) == name.lower(), _T.id != (me or 0))
        )
        if clash is not None:
            where = "among the shared templates" if shared else "among your templates"
            raise ConflictError(f"a template named {name!r} exists {where} (#{clash})")
