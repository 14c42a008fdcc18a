"""A real ergoseek server for the tests (:class:`server.harness.ServerProcess`): ``ergoseek
serve`` with the simulated machine, no dashboard, and one account of each role, whose login is
the role's name."""

from __future__ import annotations

import contextlib
from pathlib import Path

from server.harness import ROOT, ServerProcess, free_port

PASSWORDS = {"admin": "admin-pass-1", "trainer": "trainer-pass-1", "viewer": "viewer-pass-1"}
ACCOUNTS = [(role, password, role) for role, password in PASSWORDS.items()]

__all__ = ["PASSWORDS", "ROOT", "ServerProcess", "free_port", "start_server", "worker_pid"]


def start_server(
    data_dir: Path, *args: str, port: int | None = None, env: dict[str, str] | None = None
) -> ServerProcess:
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
            if ppid == server_pid and b"multiprocessing" in cmdline and b"spawn_main" in cmdline:
                return int(entry.name)
    return None
