"""Suite-wide order.

- The Docker smoke test last: it builds and runs an image on a dockerd of its own; the I/O and
  the VM's steal time around it would otherwise fall on the real-time tests (the 1 kHz worker,
  the ODrive link over a pty) that follow it alphabetically.
- Under xdist (``make test``'s parallel part, ``--dist loadfile --no-loadscope-reorder``):
  the slowest modules first, by the seconds ``tests/durations.json`` holds for them
  (:mod:`testing.durations`), so that no worker is left running a slow module alone at the end.
  Tests keep their order within a module.
"""

from __future__ import annotations

import os

import pytest

from testing.durations import load


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if os.environ.get("PYTEST_XDIST_WORKER"):  # (each worker collects the same order)
        seconds = load()
        items.sort(key=lambda item: -seconds.get(item.nodeid.split("::", 1)[0], 0.0))
    items.sort(key=lambda item: item.get_closest_marker("docker") is not None)  # stable
