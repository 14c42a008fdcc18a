"""Suite-wide order: the Docker smoke test last.

It builds and runs an image on a dockerd of its own; the I/O and the VM's steal time around it
would otherwise fall on the real-time tests (the 1 kHz worker, the ODrive link over a pty) that
follow it alphabetically.
"""

from __future__ import annotations

import pytest


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    items.sort(key=lambda item: item.get_closest_marker("docker") is not None)  # stable
