"""The trainer's workflow in the store, on SQLite and PostgreSQL: protocol templates and who
may read or change them, session phases as the pump writes them, account preferences, and a
user's progress across sessions."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from sessions.config import SessionConfig
from sessions.protocol.analysis import PhaseResult
from sessions.store import ConflictError, ForbiddenError, NotFoundError, Store, StoreValueError
from sessions.summary import SessionSummary

SEEK = {"phases": [{"kind": "seek", "duration": 60}]}
INTERVALS = {
    "name": "6 × 20/40",
    "phases": [
        {"kind": "warmup", "duration": 60},
        {"kind": "seek"},
        {"kind": "train", "intervals": 6, "work": 20, "rest": 40},
        {"kind": "cooldown"},
    ],
}


def accounts(store: Store) -> dict[str, int]:
    made = {
        "admin": store.accounts.create("admin", "admin-violet-harbour-92", "admin"),
        "ann": store.accounts.create("ann", "ann-violet-harbour-92", "trainer"),
        "bob": store.accounts.create("bob", "bob-violet-harbour-92", "trainer"),
        "vic": store.accounts.create("vic", "vic-violet-harbour-92", "viewer"),
    }
    return {k: a.id for k, a in made.items()}


ROLE = {"admin": "admin", "ann": "trainer", "bob": "trainer", "vic": "viewer"}


def names(store: Store, ids: dict[str, int], who: str) -> list[str]:
    return [t.name for t in store.templates.list(account_id=ids[who], role=ROLE[who])]


# -- templates -------------------------------------------------------------------------------
def test_a_template_round_trips_its_protocol(store: Store) -> None:
    ids = accounts(store)
    t = store.templates.create(
        ids["ann"], " Intervals ", INTERVALS, description="hard", shared=True
    )
    assert t.name == "Intervals" and t.shared and t.account_id == ids["ann"]
    back = store.templates.get(t.id, account_id=ids["bob"], role="trainer")
    # the protocol as validated: every default filled in, SI units
    assert back.protocol["phases"][2] | {"intervals": 6} == back.protocol["phases"][2]
    assert back.protocol["phases"][2]["rest_velocity"] == 1.0
    assert back.protocol["name"] == "6 × 20/40" and back.description == "hard"


def test_who_reads_and_who_changes_a_template(store: Store) -> None:
    ids = accounts(store)
    mine = store.templates.create(ids["ann"], "ann's own", SEEK)
    team = store.templates.create(ids["ann"], "team", SEEK, shared=True)
    theirs = store.templates.create(ids["bob"], "bob's own", SEEK)
    assert names(store, ids, "ann") == ["team", "ann's own"]  # shared first
    assert names(store, ids, "bob") == ["team", "bob's own"]
    assert names(store, ids, "vic") == ["team"]
    assert sorted(names(store, ids, "admin")) == ["ann's own", "bob's own", "team"]
    with pytest.raises(NotFoundError):  # another trainer's private template does not exist
        store.templates.get(mine.id, account_id=ids["bob"], role="trainer")
    with pytest.raises(NotFoundError):
        store.templates.update(theirs.id, account_id=ids["ann"], role="trainer", name="x")
    # a shared template is the team's: another trainer edits it, but cannot unshare it
    edited = store.templates.update(team.id, account_id=ids["bob"], role="trainer", name="team 2")
    assert edited.name == "team 2" and edited.account_id == ids["ann"]
    with pytest.raises(ForbiddenError):
        store.templates.update(team.id, account_id=ids["bob"], role="trainer", shared=False)
    with pytest.raises(ForbiddenError):  # a viewer reads, never writes
        store.templates.update(team.id, account_id=ids["vic"], role="viewer", name="v")
    with pytest.raises(ForbiddenError):
        store.templates.delete(team.id, account_id=ids["vic"], role="viewer")
    store.templates.update(mine.id, account_id=ids["admin"], role="admin", shared=True)
    assert names(store, ids, "bob") == ["ann's own", "team 2", "bob's own"]
    store.templates.delete(theirs.id, account_id=ids["bob"], role="trainer")
    assert names(store, ids, "admin") == ["ann's own", "team 2"]


def test_template_names_are_unique_among_one_owners_and_among_the_shared(store: Store) -> None:
    ids = accounts(store)
    store.templates.create(ids["ann"], "Tempo", SEEK)
    store.templates.create(ids["bob"], "tempo", SEEK)  # another owner's private: fine
    with pytest.raises(ConflictError, match="among your templates"):
        store.templates.create(ids["ann"], "TEMPO", SEEK)
    shared = store.templates.create(ids["ann"], "Tempo", SEEK, shared=True)  # shared scope
    with pytest.raises(ConflictError, match="among the shared templates"):
        store.templates.create(ids["bob"], "tempo", SEEK, shared=True)
    with pytest.raises(ConflictError):
        store.templates.update(shared.id, account_id=ids["ann"], role="trainer", shared=False)


@pytest.mark.parametrize(
    ("protocol", "field"),
    [
        ({"phases": [{"kind": "train", "work": -5}]}, "protocol.phases.0.train.work"),
        ({"phases": [{"kind": "seek"}, {"kind": "seek"}]}, "protocol.phases.1"),
        ({"phases": [{"kind": "warmup", "effort": 2}]}, "protocol.phases.0.warmup.effort"),
        ({"phase": []}, "protocol.phases"),  # (required; the unknown key comes second)
    ],
)
def test_a_bad_template_is_refused_naming_the_field_and_nothing_is_stored(
    store: Store, protocol: dict, field: str
) -> None:
    ids = accounts(store)
    with pytest.raises(StoreValueError) as err:
        store.templates.create(ids["ann"], "bad", protocol)
    assert err.value.field == field
    with pytest.raises(StoreValueError, match="name"):
        store.templates.create(ids["ann"], "   ", SEEK)
    assert names(store, ids, "admin") == []


def test_deleting_an_account_keeps_its_shared_templates_only(store: Store) -> None:
    ids = accounts(store)
    shared = store.templates.create(ids["ann"], "team", SEEK, shared=True)
    store.templates.create(ids["ann"], "own", SEEK)
    store.preferences.set(ids["ann"], velocity_unit="rad/s")
    store.accounts.delete(ids["ann"])
    (left,) = store.templates.list(account_id=ids["admin"], role="admin")
    assert left.id == shared.id and left.account_id is None
    with pytest.raises(NotFoundError):
        store.preferences.get(ids["ann"])


# -- preferences -----------------------------------------------------------------------------
def test_preferences_default_to_rpm_and_change(store: Store) -> None:
    ids = accounts(store)
    assert store.preferences.get(ids["vic"]).velocity_unit == "rpm"
    assert store.preferences.set(ids["vic"], velocity_unit="rad/s").velocity_unit == "rad/s"
    assert store.preferences.get(ids["vic"]).velocity_unit == "rad/s"
    with pytest.raises(StoreValueError) as err:
        store.preferences.set(ids["vic"], velocity_unit="deg/s")
    assert err.value.field == "velocity_unit"
    assert store.preferences.get(ids["vic"]).velocity_unit == "rad/s"
    with pytest.raises(NotFoundError):
        store.preferences.set(10_000, velocity_unit="rpm")


# -- phases ----------------------------------------------------------------------------------
def _session(store: Store, protocol: dict | None = INTERVALS) -> tuple[int, int]:
    user = store.users.create("Ada", body_mass_kg=64.0)
    cfg = SessionConfig.model_validate({"protocol": protocol} if protocol else {"duration": 60})
    return user.id, store.sessions.start(user.id, cfg).id


def _result(
    index: int, kind: str, start: float, end: float, power: float, at_bound: str | None = None
) -> PhaseResult:
    return PhaseResult(
        index=index, kind=kind, name=kind, start=start, end=end, mean_power=power,
        peak_power=2 * power, work=power * (end - start), mean_w=3.0,
        optimum_w=3.1 if kind in ("seek", "train") else None, at_bound=at_bound,
        detail={"note": kind},
    )  # fmt: skip


def test_a_phase_begun_ends_the_one_before_and_gets_its_summary(store: Store) -> None:
    _, sid = _session(store)
    store.phases.begin(sid, 0, "warmup", "warm-up", 0.0, planned_end=60.0)
    store.phases.begin(sid, 1, "seek", "seek 2", 60.0, planned_end=240.0)
    first, second = store.phases.list(sid)
    assert (first.t_start, first.t_end, first.mean_power) == (0.0, 60.0, None)
    assert (second.t_start, second.t_end, second.planned_end) == (60.0, None, 240.0)
    store.phases.begin(sid, 1, "seek", "seek 2", 60.0)  # again (a replay): the same row
    assert len(store.phases.list(sid)) == 2
    store.sessions.finish(sid, "completed")
    assert store.phases.close_open(sid, 131.5) == [1]
    # summaries come after the end, from the stored telemetry
    store.phases.summarize(sid, _result(0, "warmup", 0.0, 60.0, 1.0))
    store.phases.summarize(sid, _result(1, "seek", 60.0, 131.5, 2.5, at_bound="upper"))
    warm, seek = store.sessions.detail(sid).phases
    assert (warm.mean_power, warm.peak_power, warm.work, warm.optimum_w) == (1.0, 2.0, 60.0, None)
    assert (seek.t_end, seek.mean_power, seek.optimum_w) == (131.5, 2.5, 3.1)
    assert (warm.at_bound, seek.at_bound) == (None, "upper")
    assert seek.detail == {"note": "seek"}
    with pytest.raises(ConflictError):  # a phase only begins in a running session
        store.phases.begin(sid, 2, "train", "train", 140.0)


def test_bad_phases_are_refused(store: Store) -> None:
    _, sid = _session(store)
    with pytest.raises(StoreValueError) as err:
        store.phases.begin(sid, 0, "sprint", "x", 0.0)
    assert err.value.field == "kind"
    with pytest.raises(StoreValueError) as err:
        store.phases.begin(sid, 0, "seek", "x", float("nan"))
    assert err.value.field == "t_start"
    with pytest.raises(NotFoundError):
        store.phases.summarize(sid, _result(5, "seek", 0.0, 1.0, 1.0))
    assert store.phases.list(sid) == []
    store.phases.begin(sid, 0, "seek", "x", 0.0)
    with pytest.raises(StoreValueError) as err:
        store.phases.summarize(sid, _result(0, "seek", 0.0, 1.0, 1.0, at_bound="sideways"))
    assert err.value.field == "at_bound"
    (phase,) = store.phases.list(sid)
    assert phase.mean_power is None and phase.at_bound is None  # nothing of it was stored


# -- progress --------------------------------------------------------------------------------
PROFILE = {
    "model": "hill",
    **{k: {"value": v, "low": 0.9 * v, "high": 1.1 * v, "stderr": 0.05 * v}
       for k, v in (("tau0", 3.0), ("wmax", 10.0), ("pmax", 2.9), ("w_opt", 3.1), ("a", 0.25))},
    "curve": {"w": [0.0]},
}  # fmt: skip


def test_progress_lists_a_users_ended_sessions_oldest_first(store: Store) -> None:
    uid, first = _session(store)
    store.phases.begin(first, 0, "profile", "profile", 0.0)
    store.sessions.finish(
        first,
        "completed",
        SessionSummary(optimum_w=3.0, peak_power=4.0, mean_power=2.0, converged=True),
    )
    r = _result(0, "profile", 0.0, 60.0, 2.0)
    store.phases.summarize(first, PhaseResult(**{**r.__dict__, "detail": {"profile": PROFILE}}))
    second = store.sessions.start(uid, SessionConfig()).id
    store.sessions.finish(second, "stopped", SessionSummary(optimum_w=3.3, peak_power=5.0))
    running = store.sessions.start(uid, SessionConfig()).id  # not ended: not on the chart
    other = store.users.create("Bea").id
    store.sessions.finish(store.sessions.start(other, SessionConfig()).id, "completed")
    got = store.progress.user(uid)
    assert got.body_mass_kg == 64.0
    assert [p.session_id for p in got.sessions] == [first, second]
    assert running not in [p.session_id for p in got.sessions]
    a, b = got.sessions
    assert a.protocol == "6 × 20/40" and a.optimum_w == 3.0 and a.peak_power == 4.0
    (fit,) = a.profiles
    assert fit["model"] == "hill" and fit["w_opt"]["value"] == 3.1 and "curve" not in fit
    assert b.profiles == [] and b.status == "stopped" and b.protocol == ""
    assert store.progress.user(uid, statuses=("completed",)).sessions[0].session_id == first
    later = datetime.now(UTC) + timedelta(hours=1)
    assert store.progress.user(uid, since=later).sessions == []
    with pytest.raises(NotFoundError):
        store.progress.user(10_000)
