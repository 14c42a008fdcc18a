"""The API tests' parts: a real ``ergoseek serve`` in its own process per module (simulated
machine, no dashboard, an account per role whose login is the role's name:
:func:`testing.server.start_server`). A module that needs other settings overrides ``server``."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from testing.server import ServerProcess, start_server


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    with start_server(tmp_path_factory.mktemp("srv")) as srv:
        yield srv
