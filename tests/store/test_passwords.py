"""The account password policy (issue 12.5), in the store, so that every way of setting a
password (REST, CLI, the demo) meets it: a strength estimate (zxcvbn), not the login name nor
a variant of it, a longer minimum for admins; on creation and on every change."""

from __future__ import annotations

import pytest

from sessions.store import Store, StoreValueError
from sessions.store.passwords import ADMIN_MIN_LENGTH, is_login_variant

WEAK = ["12345678", "aaaaaaaa", " " * 8, "password1", "qwertyuiop", "iloveyou2024", "P@ssw0rd!"]


@pytest.mark.parametrize("password", WEAK)
@pytest.mark.parametrize("role", ["admin", "trainer", "viewer"])
def test_common_and_trivial_passwords_are_refused(store: Store, password: str, role: str) -> None:
    with pytest.raises(StoreValueError) as info:
        store.accounts.create("coach", password, role)  # type: ignore[arg-type]
    assert info.value.field == "password"
    assert store.accounts.count() == 0


@pytest.mark.parametrize(
    "password", ["coach-coach", "Coach2024!!", "hcaoc.hcaoc", "COACHCOACH", "__coach__99"]
)
def test_the_login_name_and_its_variants_are_refused(store: Store, password: str) -> None:
    with pytest.raises(StoreValueError) as info:
        store.accounts.create("coach", password, "trainer")
    assert info.value.field == "password"


def test_login_variants() -> None:
    assert is_login_variant("Coach!", "coach") and is_login_variant("hcaoc", "coach")
    assert is_login_variant("coach.coach.2", "coach")
    assert not is_login_variant("coach jumps over the lazy fox", "coach")


def test_an_admin_needs_a_longer_password(store: Store) -> None:
    strong_but_short = "vT9#qLm2xK!"  # 11 characters, strong enough for a trainer
    assert len(strong_but_short) < ADMIN_MIN_LENGTH
    with pytest.raises(StoreValueError) as info:
        store.accounts.create("root", strong_but_short, "admin")
    assert "admin" in info.value.reason and str(ADMIN_MIN_LENGTH) in info.value.reason
    assert store.accounts.create("coach", strong_but_short, "trainer").role == "trainer"


def test_a_change_of_password_meets_the_same_policy(store: Store) -> None:
    acc = store.accounts.create("coach", "correct horse battery", "trainer")
    for weak in ("12345678", "coach123", "aaaaaaaaaaaa"):
        with pytest.raises(StoreValueError):
            store.accounts.set_password(acc.id, weak)
    assert store.accounts.authenticate("coach", "correct horse battery") is not None
    store.accounts.set_password(acc.id, "staple ninth orbit")
    assert store.accounts.authenticate("coach", "staple ninth orbit") is not None
