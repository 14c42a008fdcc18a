"""``ergoseek …`` run as a user runs it: a subprocess, from the repository's root."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# ``python -m server`` is the console script's ``server.cli:main`` (``python -m server.cli``
# would load the module twice, and UsageError would not be the class main() catches)
COMMAND = [sys.executable, "-m", "server"]


def ergoseek(
    *args: str,
    stdin: str | None = None,
    env: dict[str, str] | None = None,
    cwd: Path | None = None,
    timeout: float = 120.0,
) -> subprocess.CompletedProcess[str]:
    """Run ``ergoseek ARGS`` to its end; ``env`` is added to this process's environment."""
    return subprocess.run(
        [*COMMAND, *args],
        input=stdin,
        capture_output=True,
        text=True,
        cwd=cwd or ROOT,
        env={**os.environ, **(env or {})},
        timeout=timeout,
        check=False,
    )
