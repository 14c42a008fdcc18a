"""The dashboard tests' parts: ``ergoseek demo`` in its own process (with two viewers, a
second trainer and an admin as well as the trainer ``demo``) and one headless Chromium for
the module (Debian's, driven by Playwright: :mod:`testing.browser`)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from testing.browser import CHROMIUM, DemoServer, chromium

VIEWER, VIEWER_PASSWORD = "watcher", "viewer-password-1"
VIEWER2 = "watcher2"
COACH, COACH_PASSWORD = "coach2", "coach-two-Vq83-wkzP"
CHIEF, CHIEF_PASSWORD = "chief", "chief-admin-Rt5b-Lm29-xQ"
ACCOUNTS = [
    (VIEWER, VIEWER_PASSWORD, "viewer"),
    (VIEWER2, VIEWER_PASSWORD, "viewer"),
    (COACH, COACH_PASSWORD, "trainer"),
    (CHIEF, CHIEF_PASSWORD, "admin"),
]


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DemoServer]:
    if not Path(CHROMIUM).exists():
        pytest.fail(f"{CHROMIUM} is missing: `make system` installs Debian's chromium", False)
    demo = DemoServer(tmp_path_factory.mktemp("dashboard"), accounts=ACCOUNTS)
    with demo:
        yield demo
    print(demo.log()[-2000:])


@pytest.fixture(scope="module")
def browser(server: DemoServer) -> Iterator[object]:
    with chromium() as b:
        yield b
