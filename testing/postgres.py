"""A throwaway PostgreSQL server for the store tests: Debian's ``postgresql`` binaries,
``initdb`` + ``pg_ctl`` in a temporary directory, listening on a private Unix socket, started
once per test process (:func:`postgres`).

Set ``ERGOSEEK_TEST_POSTGRES_URL`` to use an existing server instead (each test creates its
own database there). When PostgreSQL cannot be started, the PostgreSQL tests fail under CI
(``CI=true``) and are skipped with the reason elsewhere.
"""

from __future__ import annotations

import atexit
import glob
import itertools
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest


class PostgresServer:
    """A throwaway PostgreSQL cluster owned by this process."""

    def __init__(self) -> None:
        self.root: Path | None = None
        self.admin_url = ""
        self._names = itertools.count(1)
        external = os.environ.get("ERGOSEEK_TEST_POSTGRES_URL")
        if external:
            self.admin_url = external
            return
        bindir = self._bindir()
        self.root = Path(tempfile.mkdtemp(prefix="ergoseek-pg-"))
        data = self.root / "data"
        as_postgres: list[str] = []
        if os.geteuid() == 0:  # initdb refuses to run as root: run the server as postgres
            shutil.chown(self.root, user="postgres")
            as_postgres = ["runuser", "-u", "postgres", "--"]
        port = 5432  # only names the socket file in our private directory
        self._ctl = [*as_postgres, str(bindir / "pg_ctl"), "-D", str(data)]
        self._run(
            [*as_postgres, str(bindir / "initdb"), "-D", str(data), "-U", "postgres",
             "-A", "trust", "-E", "UTF8", "--no-sync", "--no-instructions"]
        )  # fmt: skip
        options = (
            f"-c listen_addresses='' -k {self.root} -p {port} -c fsync=off "
            "-c synchronous_commit=off -c full_page_writes=off -c max_connections=200"
        )
        self._run([*self._ctl, "-o", options, "-l", str(self.root / "log"), "-w", "start"])
        atexit.register(self.stop)
        self.admin_url = f"postgresql+psycopg://postgres@/postgres?host={self.root}&port={port}"

    @staticmethod
    def _bindir() -> Path:
        found = sorted(
            glob.glob("/usr/lib/postgresql/*/bin/pg_ctl"),
            key=lambda p: int(Path(p).parts[4]) if Path(p).parts[4].isdigit() else 0,
        )
        if found:
            return Path(found[-1]).parent
        which = shutil.which("pg_ctl")
        if which:
            return Path(which).parent
        raise RuntimeError("PostgreSQL binaries not found (Debian package `postgresql`)")

    @staticmethod
    def _run(cmd: list[str]) -> None:
        done = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=60)
        if done.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd[:6])}… failed: {done.stderr.strip()[-500:]}")

    def _admin(self, sql: str) -> None:
        import psycopg
        from sqlalchemy.engine import make_url

        admin = make_url(self.admin_url).set(drivername="postgresql")
        with psycopg.connect(admin.render_as_string(hide_password=False), autocommit=True) as c:
            c.execute(sql)  # type: ignore[arg-type]

    def create_database(self) -> str:
        """A new empty database; its URL."""
        from sqlalchemy.engine import make_url

        name = f"ergoseek_test_{os.getpid()}_{next(self._names)}"
        self._admin(f'CREATE DATABASE "{name}"')
        return make_url(self.admin_url).set(database=name).render_as_string(hide_password=False)

    def drop_database(self, url: str) -> None:
        from sqlalchemy.engine import make_url

        self._admin(f'DROP DATABASE IF EXISTS "{make_url(url).database}" WITH (FORCE)')

    def stop(self) -> None:
        if self.root is None:
            return
        stop = [*self._ctl, "-m", "immediate", "stop"]
        subprocess.run(stop, check=False, capture_output=True, timeout=60)
        shutil.rmtree(self.root, ignore_errors=True)
        self.root = None


_started: dict[str, PostgresServer | str] = {}  # "server" or "failure"


def postgres() -> PostgresServer:
    """The process's PostgreSQL server, started on first use."""
    if not _started:
        try:
            _started["server"] = PostgresServer()
        except Exception as exc:
            _started["failure"] = str(exc)
    server = _started.get("server")
    if not isinstance(server, PostgresServer):
        reason = f"PostgreSQL could not be started: {_started.get('failure')}"
        if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
            pytest.fail(reason)
        pytest.skip(reason)
    return server
