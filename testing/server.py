"""A real ergoseek server in its own process, for tests, benchmarks and screenshots:
``ergoseek serve`` or ``ergoseek demo`` on 127.0.0.1, a free port, its own data directory
(SQLite), accounts created beforehand, and the calls a client needs.

    with ServerProcess(tmp, accounts=[("coach", "coach-pass-1", "trainer")]).start() as srv:
        with srv.client("coach") as c: ...

:func:`start_server` is the tests' server: ``ergoseek serve`` with the simulated machine, no
dashboard, and one account of each role, whose login is the role's name.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx

from sessions.store import open_store
from sessions.store.database import SQLITE_FILENAME
from sessions.store.hashing import OWASP_MIN_MEMORY_KIB, OWASP_MIN_TIME_COST, HashCost
from testing.processes import free_port

# The tests' servers hash passwords at the least cost the server accepts (OWASP's minimum for
# argon2id, one lane): a sixth of the default's CPU per login, which the suite does ~300
# times; tests/store and tests/api check the default and the floor themselves.
TEST_HASH_COST = HashCost(
    memory_kib=OWASP_MIN_MEMORY_KIB, time_cost=OWASP_MIN_TIME_COST, parallelism=1
)

ROOT = Path(__file__).resolve().parents[1]


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of one process (all its threads, not its children), s."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def peak_rss_mb(pid: int) -> float:
    """Peak resident memory of a process (VmHWM), MiB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return round(int(line.split()[1]) / 1024, 1)
    return float("nan")


@dataclass
class ServerProcess:
    """``ergoseek <command>`` (serve or demo) with ``accounts`` (login, password, role)."""

    data_dir: Path
    command: str = "serve"
    args: list[str] = field(default_factory=list)
    accounts: list[tuple[str, str, str]] = field(default_factory=list)
    env: dict[str, str] = field(default_factory=dict)
    port: int = field(default_factory=free_port)
    proc: subprocess.Popen[bytes] | None = None
    tokens: dict[str, str] = field(default_factory=dict)
    hash_cost: HashCost | None = TEST_HASH_COST  # None: the server's default

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def ws_url(self) -> str:
        return f"ws://127.0.0.1:{self.port}"

    @property
    def database_url(self) -> str:
        """The server's database: ``env``'s ERGOSEEK_DATABASE_URL (PostgreSQL), else SQLite."""
        return (
            self.env.get("ERGOSEEK_DATABASE_URL") or f"sqlite:///{self.data_dir / SQLITE_FILENAME}"
        )

    @property
    def log_path(self) -> Path:
        return self.data_dir / f"server-{self.port}.log"

    @property
    def pid(self) -> int:
        assert self.proc is not None
        return self.proc.pid

    def passwords(self) -> dict[str, str]:
        return {login: password for login, password, _ in self.accounts}

    def start(self, timeout: float = 60.0) -> ServerProcess:
        self.data_dir.mkdir(parents=True, exist_ok=True)
        cost = self.hash_cost
        hasher = cost.hasher() if cost is not None else None
        with open_store(self.database_url, password_hasher=hasher) as store:
            for login, password, role in self.accounts:
                if store.accounts.by_login(login) is None:
                    store.accounts.create(login, password, role)  # type: ignore[arg-type]
        costs = {} if cost is None else {
            f"ERGOSEEK_PASSWORD_HASH__{key.upper()}": str(value)
            for key, value in cost.model_dump().items()
        }  # fmt: skip
        env = {**os.environ, "PYTHONUNBUFFERED": "1", **costs, **self.env}
        for leak in ("ERGOSEEK_DATABASE_URL", "ERGOSEEK_CONFIG", "ERGOSEEK_DATA_DIR"):
            if leak not in self.env:
                env.pop(leak, None)
        cmd = [
            sys.executable, "-m", "server", self.command, "--port", str(self.port),
            "--data-dir", str(self.data_dir), *self.args,
        ]  # fmt: skip
        with self.log_path.open("ab") as out:
            self.proc = subprocess.Popen(
                cmd, cwd=ROOT, env=env, stdout=out, stderr=out, start_new_session=True
            )
        self.wait_healthy(timeout)
        return self

    def wait_healthy(self, timeout: float = 60.0) -> None:
        assert self.proc is not None
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"the server exited:\n{self.log()}")
            with contextlib.suppress(httpx.HTTPError):
                r = httpx.get(f"{self.url}/healthz", timeout=2.0)
                if r.status_code == 200 and r.json()["status"] == "ok":
                    return
            time.sleep(0.1)
        self.kill()
        raise TimeoutError(f"the server did not come up:\n{self.log()}")

    def log(self) -> str:
        path = self.log_path
        return path.read_text(errors="replace")[-6000:] if path.exists() else ""

    # -- clients --------------------------------------------------------------------------------
    def token(self, login: str) -> str:
        if login not in self.tokens:
            r = httpx.post(
                f"{self.url}/api/v1/auth/token",
                json={"login": login, "password": self.passwords()[login]},
                timeout=20.0,
            )
            r.raise_for_status()
            self.tokens[login] = r.json()["access_token"]
        return self.tokens[login]

    def headers(self, login: str) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.token(login)}"}

    def client(self, login: str | None) -> httpx.Client:
        """An httpx client with a bearer token (or none, for ``login=None``)."""
        headers = self.headers(login) if login else {}
        return httpx.Client(base_url=self.url, headers=headers, timeout=20.0)

    @contextlib.contextmanager
    def browser_client(self, login: str, password: str) -> Iterator[httpx.Client]:
        """An httpx client logged in with the login cookie, from our own Origin."""
        with httpx.Client(base_url=self.url, timeout=20.0, headers={"Origin": self.url}) as c:
            c.post(
                "/api/v1/auth/login", json={"login": login, "password": password}
            ).raise_for_status()
            yield c

    def wait_status(
        self, session_id: int, statuses: set[str], timeout: float, login: str | None = None
    ) -> dict[str, Any]:
        """The session's detail once its status is one of ``statuses`` (or at the timeout)."""
        deadline = time.monotonic() + timeout
        who = login or next(iter(self.passwords()))
        with self.client(who) as c:
            while True:
                body = c.get(f"/api/v1/sessions/{session_id}").json()
                if body["session"]["status"] in statuses or time.monotonic() > deadline:
                    return body
                time.sleep(0.25)

    # -- ending -----------------------------------------------------------------------------------
    def kill(self) -> None:
        """kill -9 the web process (its worker notices and exits on its own)."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(10)

    def stop(self, timeout: float = 20.0) -> int | None:
        """SIGTERM (uvicorn's graceful shutdown), then SIGKILL the group if it hangs."""
        proc = self.proc
        if proc is None:
            return None
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(10)
        return proc.returncode

    def __enter__(self) -> ServerProcess:
        return self if self.proc is not None else self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


PASSWORDS = {"admin": "admin-pass-1", "trainer": "trainer-pass-1", "viewer": "viewer-pass-1"}
ACCOUNTS = [(role, password, role) for role, password in PASSWORDS.items()]


def start_server(
    data_dir: Path, *args: str, port: int | None = None, env: dict[str, str] | None = None
) -> ServerProcess:
    """``ergoseek serve --no-dashboard ARGS`` with an account per role, started (healthy)."""
    return ServerProcess(
        data_dir,
        "serve",
        ["--no-dashboard", *args],
        list(ACCOUNTS),
        env or {},
        port or free_port(),
    ).start()


def worker_pid(server_pid: int) -> int | None:
    """The ergoseek worker process among the server's children."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        with contextlib.suppress(OSError):
            stat = (entry / "stat").read_text()
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            cmdline = (entry / "cmdline").read_bytes()
            gate = (entry / "comm").read_text().strip() == "ergoseek-gate"  # (the e-stop gate)
            spawned = b"multiprocessing" in cmdline and b"spawn_main" in cmdline
            if ppid == server_pid and spawned and not gate:
                return int(entry.name)
    return None
