"""A real ergoseek server for the tests: ``ergoseek serve`` in a subprocess on a free port,
with its own SQLite file, a simulated machine, and one account of each role.

    with ServerProcess.start(tmp_path) as srv:
        srv.token("trainer") ...
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx

from sessions.store import open_store

PASSWORDS = {"admin": "admin-pass-1", "trainer": "trainer-pass-1", "viewer": "viewer-pass-1"}
ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def seed_accounts(data_dir: Path) -> None:
    with open_store(f"sqlite:///{data_dir / 'ergoseek.sqlite3'}") as store:
        for role, password in PASSWORDS.items():
            if store.accounts.by_login(role) is None:
                store.accounts.create(role, password, role)  # type: ignore[arg-type]


@dataclass
class ServerProcess:
    data_dir: Path
    port: int
    proc: subprocess.Popen[bytes]
    log: Path
    tokens: dict[str, str] = field(default_factory=dict)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def ws_url(self) -> str:
        return f"ws://127.0.0.1:{self.port}"

    @property
    def database_url(self) -> str:
        return f"sqlite:///{self.data_dir / 'ergoseek.sqlite3'}"

    @classmethod
    def start(
        cls, data_dir: Path, *args: str, port: int | None = None, env: dict[str, str] | None = None
    ) -> ServerProcess:
        data_dir.mkdir(parents=True, exist_ok=True)
        seed_accounts(data_dir)
        port = port or free_port()
        log = data_dir / f"server-{port}.log"
        cmd = [
            sys.executable, "-m", "server", "serve", "--port", str(port),
            "--data-dir", str(data_dir), "--no-dashboard", *args,
        ]  # fmt: skip
        full_env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        full_env.pop("ERGOSEEK_DATABASE_URL", None)
        with log.open("ab") as out:
            proc = subprocess.Popen(cmd, cwd=ROOT, env=full_env, stdout=out, stderr=out)
        srv = cls(data_dir, port, proc, log)
        srv.wait_healthy()
        return srv

    def wait_healthy(self, timeout: float = 60.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited: {self.log.read_text()[-2000:]}")
            with contextlib.suppress(httpx.HTTPError):
                r = httpx.get(f"{self.url}/healthz", timeout=1.0)
                if r.status_code == 200 and r.json()["status"] == "ok":
                    return
            time.sleep(0.1)
        raise TimeoutError(f"server not healthy: {self.log.read_text()[-2000:]}")

    def token(self, role: str) -> str:
        if role not in self.tokens:
            r = httpx.post(
                f"{self.url}/api/v1/auth/token",
                json={"login": role, "password": PASSWORDS[role]},
                timeout=10.0,
            )
            r.raise_for_status()
            self.tokens[role] = r.json()["access_token"]
        return self.tokens[role]

    def headers(self, role: str) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.token(role)}"}

    def client(self, role: str | None = "trainer") -> httpx.Client:
        headers = self.headers(role) if role else {}
        return httpx.Client(base_url=self.url, headers=headers, timeout=20.0)

    def wait_status(self, session_id: int, statuses: set[str], timeout: float) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        with self.client("viewer") as c:
            while True:
                body = c.get(f"/api/v1/sessions/{session_id}").json()
                if body["session"]["status"] in statuses or time.monotonic() > deadline:
                    return body
                time.sleep(0.25)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(10)

    def stop(self, timeout: float = 20.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        return int(self.proc.returncode)

    def __enter__(self) -> ServerProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def worker_pid(server_pid: int) -> int | None:
    """The ergoseek worker process among the server's children."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        with contextlib.suppress(OSError):
            stat = (entry / "stat").read_text()
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            cmdline = (entry / "cmdline").read_bytes()
            if ppid == server_pid and b"multiprocessing" in cmdline and b"spawn_main" in cmdline:
                return int(entry.name)
    return None
