"""The worker tests' parts: a real worker process (spawned, the simulated machine, its
shared-memory ring), shared by a module's tests; the scenarios and the follower are
:mod:`testing.live`."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from sessions.worker import Worker
from testing.live import worker_options


@pytest.fixture(scope="module")
def worker() -> Iterator[Worker]:
    with Worker(options=worker_options()) as w:
        ready = w.start()
        assert ready is not None and ready.fault is None and ready.machine == "sim"
        yield w
