"""Round trips of every model through the store's repositories, on SQLite and PostgreSQL,
and values refused at the boundary with nothing written."""

from __future__ import annotations

import math
from datetime import UTC, datetime, timedelta, timezone

import pytest

from sessions.config import parse_session_config
from sessions.seekers import Evaluation
from sessions.store import (
    UNSET,
    ConflictError,
    NotFoundError,
    Store,
    StoreValueError,
    database_url,
    default_data_dir,
)
from sessions.summary import SessionSummary
from testing.store import telemetry

CFG = parse_session_config({"duration": 30.0, "seeker": {"kind": "parabolic"}})
SUMMARY = SessionSummary(
    optimum_w=3.1,
    optimum_p=6.2,
    converged=True,
    seeker="parabolic",
    mean_power=5.5,
    peak_power=9.25,
    work=165.0,
    duration=30.0,
    passivity_min=-0.75,
    evaluations=2,
)


def _session(store: Store, **kw: object) -> tuple[int, int]:
    user = store.users.create("Ada")
    return user.id, store.sessions.start(user.id, CFG, **kw).id  # type: ignore[arg-type]


# -- round trips ---------------------------------------------------------------------------


def test_account_round_trip(store: Store) -> None:
    acc = store.accounts.create("  Trainer.One@gym ", "correct horse", "trainer")
    assert acc.login == "trainer.one@gym" and acc.role == "trainer" and not acc.disabled
    assert acc.created_at.tzinfo is not None
    assert abs(acc.created_at - datetime.now(UTC)) < timedelta(minutes=1)
    assert store.accounts.get(acc.id) == acc
    assert store.accounts.by_login("TRAINER.ONE@GYM") == acc
    assert store.accounts.authenticate("Trainer.One@gym", "correct horse") == acc
    assert store.accounts.authenticate("trainer.one@gym", "wrong horse!") is None
    assert store.accounts.authenticate("nobody", "correct horse") is None
    changed = store.accounts.update(acc.id, role="admin", disabled=True)
    assert (changed.role, changed.disabled) == ("admin", True)
    assert store.accounts.authenticate("trainer.one@gym", "correct horse") is None  # disabled
    store.accounts.update(acc.id, disabled=False)
    store.accounts.set_password(acc.id, "battery staple")
    assert store.accounts.authenticate("trainer.one@gym", "battery staple") is not None
    assert store.accounts.authenticate("trainer.one@gym", "correct horse") is None
    with pytest.raises(ConflictError, match="taken"):
        store.accounts.create("TRAINER.one@gym", "another password")
    store.accounts.create("viewer", "viewer password")
    assert [a.login for a in store.accounts.list()] == ["trainer.one@gym", "viewer"]
    assert store.accounts.count() == 2


def test_password_is_stored_as_argon2_hash(db_url: str) -> None:
    from sqlalchemy import text

    from sessions.store.database import create_store_engine

    st = Store(db_url)  # the production hasher
    st.upgrade()
    st.accounts.create("admin", "s3cret-password", "admin")
    st.close()
    engine = create_store_engine(db_url)
    with engine.connect() as conn:
        digest = conn.execute(text("SELECT password_hash FROM accounts")).scalar_one()
    engine.dispose()
    assert digest.startswith("$argon2id$") and "s3cret" not in digest


def test_user_round_trip(store: Store) -> None:
    u = store.users.create("  Bea  ", notes="knee surgery 2024", body_mass_kg=61.5, limb="left leg")
    assert (u.name, u.notes, u.body_mass_kg, u.limb) == (
        "Bea",
        "knee surgery 2024",
        61.5,
        "left leg",
    )
    assert u.created_at == u.updated_at and u.created_at.tzinfo is not None
    assert store.users.get(u.id) == u
    u2 = store.users.update(u.id, body_mass_kg=None, notes="fine now")
    assert (u2.name, u2.notes, u2.body_mass_kg, u2.limb) == ("Bea", "fine now", None, "left leg")
    assert u2.updated_at >= u.updated_at
    assert store.users.update(u.id, limb=UNSET) == store.users.get(u.id)
    store.users.create("Carl")
    store.users.create("abe")
    page = store.users.list()
    assert [x.name for x in page.items] == ["Bea", "Carl", "abe"] and page.total == 3
    found = store.users.list(search="E")
    assert {x.name for x in found.items} == {"Bea", "abe"}
    assert store.users.list(search="100%").total == 0  # LIKE wildcards are literal


def test_session_round_trip(store: Store) -> None:
    acc = store.accounts.create("coach", "coach password", "trainer")
    user_id, sid = _session(store, backend="odrive", account_id=acc.id)
    s = store.sessions.get(sid)
    assert (s.user_id, s.account_id, s.backend, s.status) == (user_id, acc.id, "odrive", "running")
    assert s.config == CFG.model_dump(mode="json")
    assert s.session_config() == CFG
    assert s.seeker == "parabolic" and s.ended_at is None and s.evaluation_count == 0
    assert s.started_at.tzinfo is not None
    done = store.sessions.finish(sid, "completed", SUMMARY)
    assert done.status == "completed" and done.ended_at is not None
    assert done.ended_at >= done.started_at
    assert done.summary() == SUMMARY
    assert store.sessions.get(sid) == done
    with pytest.raises(ConflictError, match="completed"):
        store.sessions.finish(sid, "stopped")


@pytest.mark.parametrize(
    "search",
    [
        {  # ended against the bracket: not converged, the hint the dashboard shows
            "at_bound": "upper", "converged": False, "optimum_t": 30.0, "target_min": 2.0,
            "target_max": 6.0, "regret": 0.081,
        },
        {  # converged at 11.6 s, tracked to the end
            "t_converged": 11.625, "wd_converged": 3.2, "p_converged": 6.5, "optimum_t": 30.0,
            "target_min": 1.5, "target_max": 4.75, "regret": 0.0125,
        },
    ],
)  # fmt: skip
def test_the_search_figures_round_trip(store: Store, search: dict[str, object]) -> None:
    summary = SUMMARY.model_copy(update=search)
    _, sid = _session(store)
    done = store.sessions.finish(sid, "completed", summary)
    assert done.summary() == summary
    assert store.sessions.get(sid).summary() == summary
    for name, value in search.items():
        assert getattr(done, name) == value


def test_a_summary_at_no_known_bound_is_refused(store: Store) -> None:
    _, sid = _session(store)
    bad = SUMMARY.model_dump() | {"at_bound": "sideways"}
    with pytest.raises(StoreValueError, match="at_bound"):
        store.sessions.finish(sid, "completed", bad)
    assert store.sessions.get(sid).status == "running"


def test_finish_keeps_abort_reason_and_live_figures(store: Store) -> None:
    _, sid = _session(store)
    done = store.sessions.finish(sid, "faulted", abort_reason="encoder lost")
    assert (done.status, done.abort_reason, done.duration) == ("faulted", "encoder lost", 0.0)
    summary = SUMMARY.model_copy(update={"abort_reason": "passivity bound"})
    _, sid2 = _session(store)
    assert store.sessions.finish(sid2, "aborted", summary).abort_reason == "passivity bound"


def test_evaluations_and_events_round_trip(store: Store) -> None:
    _, sid = _session(store)
    e1 = store.sessions.add_evaluation(sid, Evaluation(4.5, 2.5, 6.0, 0.05))
    e0 = store.sessions.add_evaluation(sid, Evaluation(2.0, 1.0, 3.0, math.inf))
    assert (e1.t, e1.candidate, e1.power, e1.stderr) == (4.5, 2.5, 6.0, 0.05)
    assert e0.stderr is None  # the seeker had no estimate
    ev = store.sessions.add_event(sid, 3.25, "limit", {"what": "torque", "value": 20.0})
    store.sessions.add_event(sid, 1.0, "estop")
    detail = store.sessions.detail(sid)
    assert [e.t for e in detail.evaluations] == [2.0, 4.5]
    assert detail.evaluations[1] == e1
    assert [(e.t, e.kind) for e in detail.events] == [(1.0, "estop"), (3.25, "limit")]
    assert detail.events[1] == ev and ev.detail == {"what": "torque", "value": 20.0}
    assert detail.session.evaluation_count == 2
    assert store.sessions.events(sid, kind="estop")[0].detail == {}
    store.sessions.finish(sid, "stopped")
    with pytest.raises(ConflictError, match="not running"):
        store.sessions.add_event(sid, 5.0, "fault")


def test_setpoint_round_trip_and_current(store: Store) -> None:
    user_id, sid = _session(store)
    assert store.setpoints.current(user_id) is None
    with pytest.raises(ConflictError, match="still running"):
        store.setpoints.from_session(sid)
    store.sessions.finish(sid, "completed", SUMMARY)
    t0 = datetime(2026, 1, 5, 10, 0, tzinfo=UTC)
    old = store.setpoints.record(user_id, 2.8, power=5.9, seeker="brent", created_at=t0)
    manual = store.setpoints.record(user_id, 3.0, created_at=t0 + timedelta(days=1), accepted=False)
    found = store.setpoints.from_session(sid)
    assert (found.velocity, found.power, found.seeker, found.session_id) == (
        3.1,
        6.2,
        "parabolic",
        sid,
    )
    assert (manual.power, manual.seeker, manual.accepted) == (None, "manual", False)
    assert old.created_at == t0
    assert store.setpoints.current(user_id) == found
    assert [s.id for s in store.setpoints.history(user_id)] == [found.id, manual.id, old.id]
    assert [s.id for s in store.setpoints.history(user_id, accepted_only=True)] == [
        found.id,
        old.id,
    ]
    store.setpoints.set_accepted(found.id, False)
    assert store.setpoints.current(user_id) == old
    store.setpoints.set_accepted(manual.id, True)
    assert store.setpoints.current(user_id).id == manual.id  # type: ignore[union-attr]
    other = store.users.create("Other")
    with pytest.raises(StoreValueError, match="another user"):
        store.setpoints.record(other.id, 3.0, session_id=sid)


def test_deletes_cascade(store: Store) -> None:
    acc = store.accounts.create("coach", "coach password", "trainer")
    user_id, sid = _session(store, account_id=acc.id)
    store.sessions.add_event(sid, 0.5, "info")
    rec = store.recorder(sid, background=False)
    rec.add_rows([[0.0, 0, 1, 1, 0, 0, 1, 1, 0, 1], [0.001, 0, 1, 1, 0, 0, 1, 1, 0, 1]])
    rec.finish("completed")
    point = store.setpoints.record(user_id, 2.0, session_id=sid)
    store.accounts.delete(acc.id)
    assert store.sessions.get(sid).account_id is None
    store.sessions.delete(sid)
    assert store.setpoints.history(user_id) == [point.model_copy(update={"session_id": None})]
    _, sid2 = _session(store)
    uid2 = store.sessions.get(sid2).user_id
    store.users.delete(uid2)
    with pytest.raises(NotFoundError):
        store.sessions.get(sid2)
    with pytest.raises(NotFoundError, match="session"):
        store.telemetry.load(sid2)
    assert store.check() == []


def test_transaction_commits_all_or_nothing(store: Store) -> None:
    with store.transaction():
        u = store.users.create("Dee")
        sid = store.sessions.start(u.id, CFG).id
    assert store.sessions.get(sid).user_id == u.id
    with pytest.raises(StoreValueError), store.transaction():
        store.users.create("Eve")
        store.setpoints.record(u.id, -1.0)
    assert [x.name for x in store.users.list().items] == ["Dee"]


def test_missing_rows_are_not_found(store: Store) -> None:
    for call in (
        lambda: store.users.get(99),
        lambda: store.accounts.get(99),
        lambda: store.sessions.get(99),
        lambda: store.sessions.detail(99),
        lambda: store.setpoints.current(99),
        lambda: store.sessions.start(99, CFG),
        lambda: store.telemetry.span(99),
        lambda: store.recorder(99),
    ):
        with pytest.raises(NotFoundError):
            call()


# -- queries -------------------------------------------------------------------------------


def test_session_list_filters_and_pages(store: Store) -> None:
    a = store.users.create("A").id
    b = store.users.create("B").id
    t0 = datetime(2026, 3, 1, 8, 0, tzinfo=UTC)
    ids = []
    for i in range(23):
        when = t0 + timedelta(hours=i // 2)  # pairs share a start time: id breaks the tie
        sid = store.sessions.start(a if i % 3 else b, CFG, started_at=when).id
        if i % 4 == 0:
            store.sessions.finish(sid, "completed", ended_at=when + timedelta(minutes=5))
        ids.append(sid)
    everything = store.sessions.list(limit=1000)
    assert everything.total == 23
    expected = sorted(
        ids, key=lambda i: (t0 + timedelta(hours=(ids.index(i)) // 2), i), reverse=True
    )
    assert [s.id for s in everything.items] == expected
    pages = [store.sessions.list(limit=5, offset=o) for o in range(0, 25, 5)]
    assert [s.id for p in pages for s in p.items] == expected
    assert {p.total for p in pages} == {23} and pages[-1].items.__len__() == 3
    mine = store.sessions.list(user_id=b)
    assert mine.total == 8 and all(s.user_id == b for s in mine.items)
    done = store.sessions.list(status="completed")
    assert done.total == 6 and all(s.status == "completed" for s in done.items)
    both = store.sessions.list(status=["completed", "running"], user_id=a)
    assert both.total == 15
    window = store.sessions.list(
        since=t0 + timedelta(hours=2), until=t0 + timedelta(hours=4), limit=100
    )
    assert window.total == 4
    assert all(
        t0 + timedelta(hours=2) <= s.started_at < t0 + timedelta(hours=4) for s in window.items
    )
    # a naive datetime counts as UTC; another zone is converted
    cet = timezone(timedelta(hours=1))
    assert store.sessions.list(since=datetime(2026, 3, 1, 9, 0, tzinfo=cet)).total == 23
    assert store.sessions.list(since=datetime(2026, 3, 1, 18, 0)).total == 3


def test_recover_marks_running_sessions_aborted(store: Store) -> None:
    _, sid = _session(store)
    rec = store.recorder(sid, background=False)
    rec.add_rows(telemetry(2.5))
    rec.close()  # data stored, session still running (as after a crash)
    _, finished = _session(store)
    store.sessions.finish(finished, "completed")
    assert store.sessions.recover() == [sid]
    s = store.sessions.get(sid)
    assert (s.status, s.abort_reason) == ("aborted", "server restarted")
    assert s.duration == pytest.approx(2.5)
    assert s.ended_at == s.started_at + timedelta(seconds=s.duration)
    assert store.telemetry.span(sid).samples == 2500
    assert store.sessions.recover() == []


# -- refused at the boundary ---------------------------------------------------------------


def _refused(field: str, call: object, *args: object, **kw: object) -> StoreValueError:
    with pytest.raises(StoreValueError) as info:
        call(*args, **kw)  # type: ignore[operator]
    assert info.value.field == field, str(info.value)
    assert str(info.value).startswith(f"{field}: ")
    assert isinstance(info.value, ValueError)
    return info.value


def test_bad_account_values_are_refused(store: Store) -> None:
    err = _refused("role", store.accounts.create, "root", "long enough indeed", "superuser")
    assert "unknown value 'superuser'" in str(err) and "admin, trainer, viewer" in str(err)
    _refused("login", store.accounts.create, "   ", "long enough indeed")
    _refused("login", store.accounts.create, "two words", "long enough indeed")
    _refused("password", store.accounts.create, "root", "short")
    _refused("disabled", store.accounts.create, "root", "long enough indeed", disabled="no")
    assert store.accounts.count() == 0
    acc = store.accounts.create("root", "long enough indeed", "admin")
    _refused("role", store.accounts.update, acc.id, role="owner")
    assert store.accounts.get(acc.id).role == "admin"


def test_bad_user_values_are_refused(store: Store) -> None:
    _refused("name", store.users.create, "")
    _refused("name", store.users.create, "x" * 201)
    _refused("body_mass_kg", store.users.create, "Ann", body_mass_kg=-70)
    _refused("body_mass_kg", store.users.create, "Ann", body_mass_kg=math.nan)
    _refused("body_mass_kg", store.users.create, "Ann", body_mass_kg="heavy")
    assert store.users.list().total == 0
    u = store.users.create("Ann")
    _refused("name", store.users.update, u.id, name=" ")
    assert store.users.get(u.id) == u


def test_bad_session_values_are_refused(store: Store) -> None:
    user_id = store.users.create("Ann").id
    err = _refused("config.duration", store.sessions.start, user_id, {"duration": -5})
    assert "greater than 0" in str(err)
    _refused("config.seeker.kind", store.sessions.start, user_id, {"seeker": {"kind": "magic"}})
    _refused("config.speed", store.sessions.start, user_id, {"speed": 3})
    _refused("backend", store.sessions.start, user_id, CFG, backend="Bad Backend")
    assert store.sessions.list().total == 0
    sid = store.sessions.start(user_id, CFG).id
    before = store.sessions.get(sid)
    bad = {**SUMMARY.model_dump(), "duration": -1.0}
    err = _refused("summary.duration", store.sessions.finish, sid, "completed", bad)
    assert "greater than or equal to 0" in str(err)
    # a summary built without validation is checked again
    sneaky = SessionSummary.model_construct(**{**SUMMARY.model_dump(), "mean_power": math.nan})
    _refused("summary.mean_power", store.sessions.finish, sid, "completed", sneaky)
    _refused("status", store.sessions.finish, sid, "running")
    _refused("status", store.sessions.finish, sid, "exploded")
    _refused(
        "ended_at",
        store.sessions.finish,
        sid,
        "completed",
        ended_at=before.started_at - timedelta(1),
    )
    assert store.sessions.get(sid) == before
    _refused("status", store.sessions.list, status="paused")
    _refused("limit", store.sessions.list, limit=0)
    _refused("offset", store.sessions.list, offset=-1)


def test_bad_evaluation_and_event_values_are_refused(store: Store) -> None:
    _, sid = _session(store)
    _refused("evaluation.power", store.sessions.add_evaluation, sid, Evaluation(1.0, 2.0, math.nan))
    _refused("evaluation.power", store.sessions.add_evaluation, sid, Evaluation(1.0, 2.0, math.inf))
    _refused("evaluation.t", store.sessions.add_evaluation, sid, Evaluation(-1.0, 2.0, 3.0))
    _refused(
        "evaluation.stderr", store.sessions.add_evaluation, sid, Evaluation(1.0, 2.0, 3.0, -0.1)
    )
    _refused("evaluation", store.sessions.add_evaluation, sid, object())
    _refused("kind", store.sessions.add_event, sid, 1.0, "Fault!")
    _refused("t", store.sessions.add_event, sid, math.nan, "fault")
    _refused("detail", store.sessions.add_event, sid, 1.0, "fault", {"x": math.inf})
    _refused("detail", store.sessions.add_event, sid, 1.0, "fault", ["not", "a", "dict"])
    rec = store.recorder(sid, background=False)
    _refused("evaluation.power", rec.add_evaluation, Evaluation(1.0, 2.0, math.nan))
    rec.close()
    detail = store.sessions.detail(sid)
    assert detail.evaluations == [] and detail.events == []
    assert detail.session.evaluation_count == 0


def test_bad_setpoint_values_are_refused(store: Store) -> None:
    user_id = store.users.create("Ann").id
    _refused("velocity", store.setpoints.record, user_id, math.nan)
    _refused("velocity", store.setpoints.record, user_id, 0.0)
    _refused("power", store.setpoints.record, user_id, 3.0, power=math.inf)
    _refused("seeker", store.setpoints.record, user_id, 3.0, seeker="")
    _refused("accepted", store.setpoints.record, user_id, 3.0, accepted=1)
    assert store.setpoints.history(user_id) == []


def test_data_path_and_url_from_environment(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    monkeypatch.delenv("ERGOSEEK_DATABASE_URL", raising=False)
    monkeypatch.delenv("ERGOSEEK_DATA_DIR", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.delenv("XDG_DATA_HOME", raising=False)
    assert default_data_dir() == tmp_path / ".local" / "share" / "ergoseek"
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    assert database_url() == f"sqlite:///{tmp_path / 'xdg' / 'ergoseek' / 'ergoseek.sqlite3'}"
    monkeypatch.setenv("ERGOSEEK_DATA_DIR", str(tmp_path / "data"))
    assert database_url() == f"sqlite:///{tmp_path / 'data' / 'ergoseek.sqlite3'}"
    monkeypatch.setenv("ERGOSEEK_DATABASE_URL", "postgresql://h/db")
    assert database_url() == "postgresql://h/db"
    assert database_url("sqlite:////x.db") == "sqlite:////x.db"
    monkeypatch.delenv("ERGOSEEK_DATABASE_URL")
    with Store() as st:  # the default file, created with its directory
        st.upgrade()
        assert st.current_revision() is not None
    assert (tmp_path / "data" / "ergoseek.sqlite3").is_file()
