"""Shared by the server benchmarks: the checkout on ``sys.path`` (for the harnesses in
``testing/``, which are not installed), a real server on a free port with one account per role
(the tests' harness), and the process figures they read."""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from testing.server import ServerProcess, cpu_seconds, peak_rss_mb  # noqa: E402
from testing.server import start_server as _start  # noqa: E402

__all__ = ["ServerProcess", "cpu_seconds", "peak_rss_mb", "start_server"]


def start_server(*args: str, env: dict[str, str] | None = None) -> ServerProcess:
    return _start(Path(tempfile.mkdtemp(prefix="ergoseek-bench-")), *args, env=env)
