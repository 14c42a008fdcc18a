"""The Alembic migrations shipped in the package: upgrade from empty, downgrade to nothing
and up again, the models equal to the migrated schema, and ``ergoseek db``."""

from __future__ import annotations

from pathlib import Path

import pytest
import sqlalchemy as sa
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from sqlalchemy import inspect

from server.cli import main
from sessions.config import SessionConfig
from sessions.store import Store, StoreError, open_store
from sessions.store.database import create_store_engine
from sessions.store.migrate import MIGRATIONS, head_revision
from sessions.store.models import Base
from testing.store import FAST_HASHER

TABLES = {
    "accounts", "users", "sessions", "seeker_evaluations", "setpoints", "telemetry_chunks",
    "events", "auth_tokens", "session_phases", "protocol_templates", "account_preferences",
}  # fmt: skip


def _schema(url: str) -> tuple[set[str], list[object]]:
    """Tables present, and what autogenerate would change to reach the models."""
    engine = create_store_engine(url)
    try:
        with engine.connect() as conn:
            tables = set(inspect(conn).get_table_names())
            ctx = MigrationContext.configure(conn, opts={"compare_type": True})
            diff = compare_metadata(ctx, Base.metadata)
    finally:
        engine.dispose()
    return tables, diff


def test_upgrade_from_empty_downgrade_and_upgrade_again(db_url: str) -> None:
    st = Store(db_url, password_hasher=FAST_HASHER)
    try:
        assert st.current_revision() is None
        with pytest.raises(StoreError, match="db upgrade"):
            open_store(db_url, upgrade=False)
        st.upgrade()
        assert st.current_revision() == head_revision() == "0005"
        tables, diff = _schema(db_url)
        assert tables == TABLES | {"alembic_version"}
        assert diff == []
        user = st.users.create("before")
        st.downgrade("base")
        assert st.current_revision() is None
        assert _schema(db_url)[0] <= {"alembic_version"}
        st.upgrade()
        assert st.current_revision() == "0005"
        tables, diff = _schema(db_url)
        assert tables == TABLES | {"alembic_version"} and diff == []
        again = st.users.create("after")
        assert again.id == user.id  # a fresh table
        st.upgrade()  # at head: nothing to do
    finally:
        st.close()
    reopened = open_store(db_url, upgrade=False, password_hasher=FAST_HASHER)
    assert reopened.users.get(again.id).name == "after"
    reopened.close()


def test_migrations_ship_with_the_package() -> None:
    assert (MIGRATIONS / "env.py").is_file()
    assert (MIGRATIONS / "script.py.mako").is_file()
    assert sorted(p.name for p in (MIGRATIONS / "versions").glob("*.py")) == [
        "0001_initial.py",
        "0002_auth_tokens_sim_profile.py",
        "0003_session_search.py",
        "0004_protocols_phases_preferences.py",
        "0005_phase_at_bound.py",
    ]
    assert not list(Path(MIGRATIONS).rglob("alembic.ini"))


def test_db_command_upgrade_and_current(
    db_url: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("ERGOSEEK_DATABASE_URL", db_url)
    if db_url.startswith("sqlite"):
        assert main(["db", "current"]) == 2
        assert "no database at" in capsys.readouterr().err
    else:
        assert main(["db", "current"]) == 0
        assert "revision none (empty)" in capsys.readouterr().out
    assert main(["db", "upgrade"]) == 0
    out = capsys.readouterr().out
    assert out.strip().endswith("revision 0005 (newest)")
    monkeypatch.delenv("ERGOSEEK_DATABASE_URL")
    assert main(["db", "current", "--url", db_url]) == 0
    assert "revision 0005 (newest)" in capsys.readouterr().out


def test_upgrade_from_the_first_revision_keeps_the_data(db_url: str) -> None:
    st = Store(db_url, password_hasher=FAST_HASHER)
    try:
        st.upgrade("0001")
        with st._db.session(write=True) as s:  # a user written by the first schema
            s.execute(
                sa.text(
                    "INSERT INTO users (name, notes, created_at, updated_at) "
                    "VALUES ('Ada', '', CURRENT_TIMESTAMP, CURRENT_TIMESTAMP)"
                )
            )
        st.upgrade()
        (ada,) = st.users.list().items
        assert ada.name == "Ada" and ada.sim_profile is None
        st.downgrade("0001")
        assert st.current_revision() == "0001"
    finally:
        st.close()


def test_0003_and_0004_up_and_down_keep_the_sessions_before_them(db_url: str) -> None:
    # a session stored at 0002 reads back at 0003 with the search's figures unknown (None);
    # 0004 adds the workflow's tables and nothing to sessions; down to 0003 those tables go
    # (the search's columns stay), down to 0002 the search's columns go, the session stays
    st = Store(db_url, password_hasher=FAST_HASHER)
    try:
        st.upgrade("0002")
        assert "session_phases" not in _schema(db_url)[0]
        with st._db.session(write=True) as s:
            s.execute(sa.text(
                "INSERT INTO users (name, notes, created_at, updated_at) "
                "VALUES ('Ada', '', CURRENT_TIMESTAMP, CURRENT_TIMESTAMP)"
            ))  # fmt: skip
        user = st.users.list().items[0]
        with st._db.session(write=True) as s:
            s.execute(
                sa.text(
                    "INSERT INTO sessions (user_id, backend, config, status, started_at, seeker,"
                    " converged, mean_power, peak_power, work, duration, passivity_min,"
                    " evaluation_count, optimum_w) VALUES (:u, 'sim', :c, 'completed',"
                    " CURRENT_TIMESTAMP, 'brent', true, 1.5, 3.0, 90.0, 60.0, 0.0, 5, 3.1)"
                ),
                {"u": user.id, "c": '{"duration": 60.0}'},
            )
        st.upgrade("0003")
        assert "session_phases" not in _schema(db_url)[0]
        with st._db.session(write=False) as s:
            row = s.execute(sa.text("SELECT optimum_w, at_bound, regret FROM sessions")).one()
        assert tuple(row) == (3.1, None, None)
        st.upgrade()  # 0004, and 0005 (the phases' bound) that today's models read
        (old,) = st.sessions.list().items
        assert old.optimum_w == 3.1 and old.regret is None and old.at_bound is None
        assert old.wd_converged is None and old.t_converged is None and old.optimum_t is None
        assert st.sessions.detail(old.id).phases == []
        account = st.accounts.create("coach", "a-long-password", "trainer")
        st.templates.create(account.id, "t", {"phases": [{"kind": "seek"}]})
        st.preferences.set(account.id, velocity_unit="rad/s")
        st.downgrade("0003")
        tables, _ = _schema(db_url)
        assert not tables & {"session_phases", "protocol_templates", "account_preferences"}
        with st._db.session(write=False) as s:
            cols = {c["name"] for c in inspect(s.connection()).get_columns("sessions")}
        assert {"regret", "at_bound", "optimum_t"} <= cols
        st.downgrade("0002")
        with st._db.session(write=False) as s:
            cols = {c["name"] for c in inspect(s.connection()).get_columns("sessions")}
            (optimum,) = s.execute(sa.text("SELECT optimum_w FROM sessions")).one()
        assert "regret" not in cols and "at_bound" not in cols and optimum == 3.1
        st.upgrade()
        assert _schema(db_url)[1] == []
    finally:
        st.close()


def test_0005_adds_each_phases_bound_and_keeps_the_phases_before_it(db_url: str) -> None:
    # a phase stored at 0004 reads back at 0005 with no bound (unknown: NULL); a bound stored
    # at 0005 is checked by the database itself; down to 0004 the column goes, the phase stays
    st = Store(db_url, password_hasher=FAST_HASHER)
    try:
        st.upgrade("0004")
        user = st.users.create("Ada")
        sid = st.sessions.start(user.id, SessionConfig.model_validate({"duration": 60})).id
        with st._db.session(write=True) as s:  # as 0004's code wrote it
            s.execute(
                sa.text(
                    "INSERT INTO session_phases (session_id, position, kind, name, t_start,"
                    " detail) VALUES (:s, 0, 'seek', 'seek 1', 0.0, '{}')"
                ),
                {"s": sid},
            )
        st.upgrade("0005")
        (phase,) = st.phases.list(sid)
        assert (phase.kind, phase.at_bound) == ("seek", None)
        with st._db.session(write=True) as s:
            s.execute(sa.text("UPDATE session_phases SET at_bound = 'upper'"))
        assert st.phases.list(sid)[0].at_bound == "upper"
        with pytest.raises(sa.exc.IntegrityError), st._db.session(write=True) as s:
            s.execute(sa.text("UPDATE session_phases SET at_bound = 'sideways'"))
        st.downgrade("0004")
        with st._db.session(write=False) as s:
            cols = {c["name"] for c in inspect(s.connection()).get_columns("session_phases")}
            (name,) = s.execute(sa.text("SELECT name FROM session_phases")).one()
        assert "at_bound" not in cols and name == "seek 1"
        st.upgrade()
        assert _schema(db_url)[1] == []
    finally:
        st.close()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["db", "current", "--url", "mysql://h/db"], "unsupported database 'mysql'"),
        (["db", "upgrade", "--url", "not a url"], "not a database URL"),
        (["db", "upgrade", "--url", "sqlite://"], "in-memory SQLite is not supported"),
        (["db", "current", "--url", "postgresql://x@127.0.0.1:9/none"], "connection"),
    ],
)
def test_db_command_errors_are_one_line(
    args: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and err.startswith("ergoseek db: error: ")


def test_db_command_unknown_revision(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    url = f"sqlite:///{tmp_path / 'x.sqlite3'}"
    assert main(["db", "upgrade", "--url", url, "--revision", "9999"]) == 2
    assert "9999" in capsys.readouterr().err
