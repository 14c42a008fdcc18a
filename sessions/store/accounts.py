"""Accounts: who may log in to the server, with which role. Passwords are kept as argon2id
hashes (argon2-cffi); hashing happens outside any transaction. Login names are
case-insensitive: stored lowercased."""

from __future__ import annotations

import re
from typing import Any

from argon2 import PasswordHasher
from argon2.exceptions import InvalidHashError, VerificationError
from sqlalchemy import delete, func, select
from sqlalchemy.exc import IntegrityError

from sessions.codes import ROLES, Role
from sessions.store import validate as v
from sessions.store.database import Database
from sessions.store.errors import ConflictError, NotFoundError, StoreValueError
from sessions.store.models import Account, ProtocolTemplate
from sessions.store.passwords import check_password
from sessions.store.records import AccountRecord

_LOGIN = re.compile(r"[a-z0-9][a-z0-9._@-]*")


def _login(value: Any) -> str:
    login = v.text("login", value, max_len=64).lower()
    if not _LOGIN.fullmatch(login):
        raise StoreValueError(
            "login", f"{login!r} may hold only letters, digits and . _ @ - (not first)"
        )
    return login


class AccountRepository:
    def __init__(self, db: Database, hasher: PasswordHasher) -> None:
        self._db = db
        self._hasher = hasher
        self._dummy: str | None = None

    def create(
        self, login: str, password: str, role: Role = "viewer", *, disabled: bool = False
    ) -> AccountRecord:
        """A new account; :class:`ConflictError` if the login name is taken."""
        name = _login(login)
        role = v.choice("role", role, ROLES)  # type: ignore[assignment]
        disabled = v.flag("disabled", disabled)
        digest = self._hasher.hash(check_password(password, name, role))
        try:
            with self._db.session(write=True) as s:
                if s.scalar(select(Account.id).where(Account.login == name)) is not None:
                    raise ConflictError(f"login name {name!r} is taken")
                row = Account(login=name, password_hash=digest, role=role, disabled=disabled)
                s.add(row)
                s.flush()
                return AccountRecord.model_validate(row)
        except IntegrityError:  # lost a race with another process creating the same name
            raise ConflictError(f"login name {name!r} is taken") from None

    def get(self, account_id: int) -> AccountRecord:
        with self._db.session(write=False) as s:
            row = s.get(Account, account_id)
            if row is None:
                raise NotFoundError("account", account_id)
            return AccountRecord.model_validate(row)

    def by_login(self, login: str) -> AccountRecord | None:
        name = str(login).strip().lower()
        with self._db.session(write=False) as s:
            row = s.scalar(select(Account).where(Account.login == name))
            return None if row is None else AccountRecord.model_validate(row)

    def list(self) -> list[AccountRecord]:
        """Every account, by login name."""
        with self._db.session(write=False) as s:
            rows = s.scalars(select(Account).order_by(Account.login))
            return [AccountRecord.model_validate(r) for r in rows]

    def count(self) -> int:
        with self._db.session(write=False) as s:
            return int(s.scalar(select(func.count()).select_from(Account)) or 0)

    def update(
        self, account_id: int, *, role: Role | None = None, disabled: bool | None = None
    ) -> AccountRecord:
        if role is not None:
            role = v.choice("role", role, ROLES)  # type: ignore[assignment]
        if disabled is not None:
            disabled = v.flag("disabled", disabled)
        with self._db.session(write=True) as s:
            row = s.get(Account, account_id)
            if row is None:
                raise NotFoundError("account", account_id)
            if role is not None:
                row.role = role
            if disabled is not None:
                row.disabled = disabled
            s.flush()
            return AccountRecord.model_validate(row)

    def set_password(self, account_id: int, password: str) -> None:
        """A new password, if the policy takes it for this account's login and role."""
        account = self.get(account_id)
        digest = self._hasher.hash(check_password(password, account.login, account.role))
        self._store_digest(account_id, digest)

    def _store_digest(self, account_id: int, digest: str) -> None:
        with self._db.session(write=True) as s:
            row = s.get(Account, account_id)
            if row is None:
                raise NotFoundError("account", account_id)
            row.password_hash = digest

    def authenticate(self, login: str, password: str) -> AccountRecord | None:
        """The account if the password matches and the account is enabled, else None. An
        unknown login costs the same hashing time as a wrong password."""
        name = str(login).strip().lower()
        with self._db.session(write=False) as s:
            row = s.scalar(select(Account).where(Account.login == name))
            found = None if row is None else (AccountRecord.model_validate(row), row.password_hash)
        if found is None:
            if self._dummy is None:
                self._dummy = self._hasher.hash("no such account")
            self._verify(self._dummy, str(password))
            return None
        record, digest = found
        if not self._verify(digest, str(password)) or record.disabled:
            return None
        if self._hasher.check_needs_rehash(digest):  # (a password that was let in before)
            self._store_digest(record.id, self._hasher.hash(str(password)))
        return record

    def delete(self, account_id: int) -> None:
        """Remove an account; the sessions it started stay, with no starter, and so do its
        shared protocol templates; its private templates go with it."""
        with self._db.session(write=True) as s:
            row = s.get(Account, account_id)
            if row is None:
                raise NotFoundError("account", account_id)
            s.execute(
                delete(ProtocolTemplate).where(
                    ProtocolTemplate.account_id == account_id, ProtocolTemplate.shared.is_(False)
                )
            )
            s.delete(row)

    def _verify(self, digest: str, password: str) -> bool:
        try:
            return self._hasher.verify(digest, password)
        except (VerificationError, InvalidHashError):
            return False
