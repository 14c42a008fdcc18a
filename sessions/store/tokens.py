"""Logins: browser sessions (cookie) and API clients' bearer tokens.

A token is 32 random bytes (URL-safe base64) handed to the client once; the store keeps its
SHA-256 digest, the account, the kind and the expiry. Resolving a token checks the digest,
expiry, revocation and that the account is still enabled, in one query.
"""

from __future__ import annotations

import hashlib
import secrets
from datetime import datetime, timedelta

from sqlalchemy import delete, select, update

from sessions.codes import TOKEN_KINDS
from sessions.store import validate as v
from sessions.store.database import Database
from sessions.store.errors import StoreValueError
from sessions.store.models import Account, AuthToken, utcnow
from sessions.store.records import AccountRecord, TokenRecord


def digest(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


class TokenRepository:
    def __init__(self, db: Database) -> None:
        self._db = db

    def issue(self, account_id: int, kind: str, lifetime: timedelta) -> tuple[str, TokenRecord]:
        """A new token for an account: the secret (shown once) and its record."""
        kind = v.choice("kind", kind, TOKEN_KINDS)
        if lifetime <= timedelta(0):
            raise StoreValueError("lifetime", "must be positive")
        token = secrets.token_urlsafe(32)
        now = utcnow()
        with self._db.session(write=True) as s:
            row = AuthToken(
                account_id=account_id,
                digest=digest(token),
                kind=kind,
                created_at=now,
                expires_at=now + lifetime,
                revoked=False,
            )
            s.add(row)
            s.flush()
            return token, TokenRecord.model_validate(row)

    def resolve(self, token: str, *, now: datetime | None = None) -> AccountRecord | None:
        """The account a live token belongs to; None for an unknown, expired or revoked
        token, or a disabled account."""
        if not token or len(token) > 256:
            return None
        with self._db.session(write=False) as s:
            row = s.scalar(
                select(Account)
                .join(AuthToken, AuthToken.account_id == Account.id)
                .where(
                    AuthToken.digest == digest(token),
                    AuthToken.revoked.is_(False),
                    AuthToken.expires_at > (now or utcnow()),
                    Account.disabled.is_(False),
                )
            )
            return None if row is None else AccountRecord.model_validate(row)

    def live(self, *, now: datetime | None = None) -> list[tuple[str, AccountRecord, datetime]]:
        """Every live login: its digest, its (enabled) account and its expiry. (A copy kept
        elsewhere, as the e-stop gate keeps one, is refreshed whenever logins change.)"""
        with self._db.session(write=False) as s:
            rows = s.execute(
                select(AuthToken.digest, AuthToken.expires_at, Account)
                .join(Account, AuthToken.account_id == Account.id)
                .where(
                    AuthToken.revoked.is_(False),
                    AuthToken.expires_at > (now or utcnow()),
                    Account.disabled.is_(False),
                )
            ).all()
            return [(d, AccountRecord.model_validate(a), e) for d, e, a in rows]

    def revoke(self, token: str) -> bool:
        """End one login; True if it existed."""
        with self._db.session(write=True) as s:
            result = s.execute(
                update(AuthToken).where(AuthToken.digest == digest(token)).values(revoked=True)
            )
            return bool(result.rowcount)

    def revoke_account(self, account_id: int) -> int:
        """End every login of an account (password change, account disabled)."""
        with self._db.session(write=True) as s:
            result = s.execute(
                update(AuthToken).where(AuthToken.account_id == account_id).values(revoked=True)
            )
            return int(result.rowcount or 0)

    def purge(self, *, now: datetime | None = None) -> int:
        """Forget expired and revoked logins."""
        with self._db.session(write=True) as s:
            result = s.execute(
                delete(AuthToken).where(
                    (AuthToken.expires_at <= (now or utcnow())) | AuthToken.revoked.is_(True)
                )
            )
            return int(result.rowcount or 0)
