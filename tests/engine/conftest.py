"""The engine tests need no server, worker or device: the engine alone (the plant, the
simulated people, the controllers, the filters, the seekers, the loop), and for the command
line a scenario file (``scenario_file``) and :func:`testing.cli.ergoseek`."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest


@pytest.fixture
def scenario_file(tmp_path: Path) -> Callable[..., Path]:
    """Write a TOML scenario in the test's directory; returns its path."""

    def write(text: str, name: str = "s.toml") -> Path:
        path = tmp_path / name
        path.write_text(text)
        return path

    return write
