"""Logins and simulation profiles in the store, on SQLite and PostgreSQL."""

from __future__ import annotations

from datetime import timedelta

import pytest

from sessions.config import UserConfig
from sessions.store import Store, StoreValueError
from sessions.store.models import utcnow


def test_a_token_resolves_until_revoked_or_expired(store: Store) -> None:
    acc = store.accounts.create("coach", "correct horse", "trainer")
    token, rec = store.tokens.issue(acc.id, "bearer", timedelta(hours=1))
    assert rec.account_id == acc.id and rec.kind == "bearer" and not rec.revoked
    assert len(token) >= 40
    assert store.tokens.resolve(token) == acc
    assert store.tokens.resolve(token + "x") is None
    assert store.tokens.resolve(token, now=utcnow() + timedelta(hours=2)) is None  # expired
    assert store.tokens.revoke(token)
    assert store.tokens.resolve(token) is None
    assert store.tokens.purge() == 1


def test_disabling_an_account_ends_its_logins(store: Store) -> None:
    acc = store.accounts.create("viewer1", "correct horse", "viewer")
    token, _ = store.tokens.issue(acc.id, "cookie", timedelta(hours=1))
    store.accounts.update(acc.id, disabled=True)
    assert store.tokens.resolve(token) is None
    store.accounts.update(acc.id, disabled=False)
    assert store.tokens.resolve(token) == store.accounts.get(acc.id)
    assert store.tokens.revoke_account(acc.id) == 1
    assert store.tokens.resolve(token) is None


def test_only_the_digest_is_stored(store: Store) -> None:
    acc = store.accounts.create("coach2", "correct horse", "trainer")
    token, _ = store.tokens.issue(acc.id, "cookie", timedelta(minutes=5))
    with store._db.session(write=False) as s:
        from sessions.store.models import AuthToken

        (row,) = s.query(AuthToken).all()
        assert token not in row.digest and len(row.digest) == 64


def test_bad_token_requests_are_refused(store: Store) -> None:
    acc = store.accounts.create("coach3", "correct horse", "trainer")
    with pytest.raises(StoreValueError, match="kind"):
        store.tokens.issue(acc.id, "forever", timedelta(hours=1))
    with pytest.raises(StoreValueError, match="lifetime"):
        store.tokens.issue(acc.id, "bearer", timedelta(0))


def test_a_users_simulation_profile_round_trips(store: Store) -> None:
    prof = UserConfig(kind="linear", tau0=2.0, wmax=6.0, noise=0.02)
    u = store.users.create("Sim", sim_profile=prof)
    assert UserConfig.model_validate(store.users.get(u.id).sim_profile) == prof
    store.users.update(u.id, sim_profile=None)
    assert store.users.get(u.id).sim_profile is None
    with pytest.raises(StoreValueError, match=r"sim_profile.*tau0"):
        store.users.update(u.id, sim_profile={"tau0": -1})
    assert store.users.get(u.id).sim_profile is None  # nothing changed
