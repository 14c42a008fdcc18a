"""Account preferences: how an account reads numbers (velocity in rpm or rad/s). The REST
API and the store stay SI; the dashboard converts for the person reading."""

from __future__ import annotations

from sessions.store import validate as v
from sessions.store.database import Database
from sessions.store.errors import NotFoundError
from sessions.store.models import Account, AccountPreferences, utcnow
from sessions.store.records import PreferencesRecord
from sessions.units import VELOCITY_UNITS

DEFAULT_VELOCITY_UNIT = "rpm"  # what trainers and every fitness tool speak


class PreferencesRepository:
    def __init__(self, db: Database) -> None:
        self._db = db

    def get(self, account_id: int) -> PreferencesRecord:
        """The account's preferences (the defaults if it never set any)."""
        with self._db.session(write=False) as s:
            if s.get(Account, account_id) is None:
                raise NotFoundError("account", account_id)
            row = s.get(AccountPreferences, account_id)
            if row is None:
                return PreferencesRecord(
                    account_id=account_id, velocity_unit=DEFAULT_VELOCITY_UNIT, updated_at=None
                )
            return PreferencesRecord.model_validate(row)

    def set(self, account_id: int, *, velocity_unit: str) -> PreferencesRecord:
        unit = v.choice("velocity_unit", velocity_unit, VELOCITY_UNITS)
        with self._db.session(write=True) as s:
            if s.get(Account, account_id) is None:
                raise NotFoundError("account", account_id)
            row = s.get(AccountPreferences, account_id)
            if row is None:
                row = AccountPreferences(account_id=account_id)
                s.add(row)
            row.velocity_unit = unit
            row.updated_at = utcnow()
            s.flush()
            return PreferencesRecord.model_validate(row)
