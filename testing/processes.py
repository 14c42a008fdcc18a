"""What ``/proc`` says of a process (for tests that wait for one to end), and a free port."""

from __future__ import annotations

import os
import socket


def state(pid: int) -> str | None:
    """The process's state letter (R, S, D, Z, X, …), None once it is gone. (The name in
    parentheses may hold spaces or parentheses: the fields after the last ``)`` are read.)"""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return None


def exited(pid: int, *, threads: bool = False) -> bool:
    """Gone, or a zombie its parent has not reaped yet; with ``threads``, also none of its
    threads left (a zombie leader's other threads may still hold its pipes and devices)."""
    s = state(pid)
    if s is None:
        return True
    if s not in ("Z", "X"):
        return False
    if not threads:
        return True
    try:
        return len(os.listdir(f"/proc/{pid}/task")) <= 1
    except FileNotFoundError:
        return True


def python_output(source: str, timeout: float = 60.0) -> str:
    """What a fresh interpreter prints running ``source`` from the project's root."""
    import subprocess
    import sys

    from testing.cli import ROOT

    out = subprocess.run(
        [sys.executable, "-c", source],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
        timeout=timeout,
    )
    return out.stdout


def loaded_after(imports: str, modules: tuple[str, ...]) -> list[str]:
    """Which of ``modules`` a fresh interpreter has in ``sys.modules`` after running
    ``imports`` (Python source) from the project's root: what an import drags in."""
    probe = f"{imports}\nimport sys\nprint(' '.join(m for m in {modules!r} if m in sys.modules))"
    return python_output(probe).split()


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on (the kernel's pick, released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
