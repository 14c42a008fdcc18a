"""``python -m testing.screenshot [OUT]``: a screenshot of the dashboard mid-session (default
``docs/img/dashboard.png``): ``ergoseek demo`` with a fresh data directory, the demo user Ada
on the simulated machine, headless Chromium at 1500×950."""

from __future__ import annotations

import argparse
import contextlib
import tempfile
import time
from pathlib import Path

from testing.browser import (
    TRAINER,
    VIEWPORT,
    DemoServer,
    chromium,
    login,
    pick,
    readout,
    set_number,
)

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "docs" / "img" / "dashboard.png"


def dismiss_notifications(page: object) -> None:
    """Close the client's toasts (headless Chromium renders WebGL in software and viser says
    so), best effort."""
    buttons = page.locator(".mantine-Notification-root button")  # type: ignore[attr-defined]
    for i in range(buttons.count()):
        with contextlib.suppress(Exception):
            buttons.nth(i).click(timeout=2000)


def capture(out: Path, at_seconds: float = 15.5) -> Path:
    with tempfile.TemporaryDirectory() as tmp, DemoServer(Path(tmp)) as server, chromium() as b:
        page = b.new_page(viewport=VIEWPORT)
        login(page, server.url, TRAINER, server.password)
        pick(page, "User", "Ada (#1)")
        set_number(page, "Duration (s)", 40)
        page.get_by_role("button", name="Start", exact=True).click()
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            r = readout(page)
            if r is not None and r["t"] >= at_seconds:
                break
            time.sleep(0.2)
        dismiss_notifications(page)
        time.sleep(0.5)
        out.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(out))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out", nargs="?", type=Path, default=DEFAULT_OUT)
    p.add_argument("--at", type=float, default=15.5, help="session time of the shot, s")
    args = p.parse_args()
    print(capture(args.out, args.at))


if __name__ == "__main__":
    main()
